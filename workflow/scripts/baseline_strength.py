# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_baseline_strength

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_baseline_strength(snakemake.config, snakemake.wildcards.model, snakemake.input.directions, snakemake.output[0])
