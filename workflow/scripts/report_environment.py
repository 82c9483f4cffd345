# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.runinfo import stage_environment

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_environment(snakemake.config, snakemake.output[0])
