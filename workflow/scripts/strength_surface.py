# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.chapter4 import stage_strength_surface
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_strength_surface(snakemake.config, snakemake.wildcards.kinematic, snakemake.wildcards.muscles,
                           snakemake.input.directions, snakemake.output.strength, snakemake.output.activation)
