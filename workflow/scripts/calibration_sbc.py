# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.calibration import calibration_sbc
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    o = snakemake.output
    calibration_sbc(rule_settings(snakemake), snakemake.wildcards.named, snakemake.input.directions, o.rows,
                    o.summary, o.groups)
