# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_appendix_a4

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_appendix_a4(snakemake.config, snakemake.input.directions, snakemake.input.baseline, snakemake.output.table, snakemake.output.figure)
