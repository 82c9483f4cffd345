# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.mfi.stages import stage_reliability

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_reliability(snakemake.config, snakemake.input.data, snakemake.output.table, snakemake.output.figure)
