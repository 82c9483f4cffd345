# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter3 import chapter3_vs_thesis
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    i = snakemake.input
    chapter3_vs_thesis(rule_settings(snakemake), i.statistics, i.reliability, i.tests, i.pairwise, i.table,
                    snakemake.output.table, snakemake.output.summary)
