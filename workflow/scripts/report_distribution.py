# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.pipeline.reruns import report_distribution
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    report_distribution(rule_settings(snakemake), list(snakemake.input.bands), snakemake.input.scorecard,
                        snakemake.output.table, snakemake.output.summary,
                        snakemake.output.spread)
