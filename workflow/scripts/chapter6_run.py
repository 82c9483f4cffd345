# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.chapter6 import stage_sequential_run
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_sequential_run(snakemake.config, snakemake.wildcards.named, snakemake.wildcards.dataset,
                         snakemake.input.directions, dict(snakemake.output.items()))
