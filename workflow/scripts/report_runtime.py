# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.report import report_runtime
from neckstrength.pipeline.common import rule_log
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    report_runtime(snakemake.params.metadata, snakemake.output.jobs, snakemake.output.by_rule,
                  exclude_rules=[snakemake.rule])
