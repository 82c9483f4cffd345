# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.
import sys

from neckstrength.pipeline.chapter3 import chapter3_vs_thesis
from neckstrength.pipeline.common import rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    i = snakemake.input
    chapter3_vs_thesis(rule_settings(snakemake), i.statistics, i.reliability, i.tests, i.pairwise, i.table,
                    snakemake.output.table, snakemake.output.summary)
