# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_full_model

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_full_model(snakemake.config, snakemake.output.table, snakemake.output.compare)
