# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter5 import chapter5_smc
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    i, o = snakemake.input, snakemake.output
    chapter5_smc(rule_settings(snakemake), snakemake.wildcards.model, snakemake.wildcards.dataset, i.directions,
                  i.estimate, i.summary, o.table, o.generations)
