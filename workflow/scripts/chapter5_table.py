# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter5 import chapter5_table
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    chapter5_table(rule_settings(snakemake), snakemake.wildcards.named, snakemake.params.datasets,
                    list(snakemake.input.estimates), list(snakemake.input.summaries), snakemake.output[0])
