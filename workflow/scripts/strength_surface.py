# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_strength_surface

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_strength_surface(snakemake.config, snakemake.wildcards.kinematic, snakemake.wildcards.muscles,
                           snakemake.input.directions, snakemake.output.strength, snakemake.output.activation)
