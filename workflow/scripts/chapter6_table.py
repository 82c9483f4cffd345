# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_sequential import stage_sequential_table

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_sequential_table(snakemake.config, snakemake.wildcards.named, snakemake.params.datasets,
                           list(snakemake.input.estimates), list(snakemake.input.summaries),
                           snakemake.output.table, snakemake.output.stop)
