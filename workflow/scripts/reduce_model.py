# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_reduce

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_reduce(snakemake.config, snakemake.wildcards.model, snakemake.output.params, snakemake.output.jacobian, snakemake.output.groups)
