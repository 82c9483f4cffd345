# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_directions

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_directions(snakemake.config, snakemake.output[0])
