# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_sequential import stage_order_comparison

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_order_comparison(snakemake.config, snakemake.input.directions, snakemake.output.table,
                           snakemake.output.figure)
