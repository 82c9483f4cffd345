# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.
import sys

from neckstrength.pipeline.report import report_runtime
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    report_runtime(snakemake.params.metadata, snakemake.output.jobs, snakemake.output.by_rule,
                  exclude_rules=[snakemake.rule])
