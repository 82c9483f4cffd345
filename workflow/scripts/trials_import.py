# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.pipeline.trials import trials_import
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    trials_import(rule_settings(snakemake), snakemake.wildcards.trialset, snakemake.input.trials,
                  snakemake.input.directions, dict(snakemake.output.items()))
