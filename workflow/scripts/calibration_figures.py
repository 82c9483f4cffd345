# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.calibration import calibration_figures
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    calibration_figures(rule_settings(snakemake), snakemake.wildcards.named, snakemake.input.rows,
                        snakemake.output.ranks, snakemake.output.coverage)
