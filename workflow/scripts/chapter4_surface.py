# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter4 import chapter4_surface
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    chapter4_surface(rule_settings(snakemake), snakemake.wildcards.kinematic, snakemake.wildcards.muscles,
                           snakemake.input.directions, snakemake.output.strength, snakemake.output.activation)
