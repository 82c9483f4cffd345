# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter5 import chapter5_estimate
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    chapter5_estimate(rule_settings(snakemake), snakemake.wildcards.model, snakemake.wildcards.dataset,
                       snakemake.input.directions, dict(snakemake.output.items()), snakemake.threads)
