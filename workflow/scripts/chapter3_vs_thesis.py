# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.chapter3 import stage_vs_thesis
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    i = snakemake.input
    stage_vs_thesis(snakemake.config, i.statistics, i.reliability, i.tests, i.pairwise, i.table,
                    snakemake.output.table, snakemake.output.summary)
