# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.mfi.stages import stage_vs_thesis

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    i = snakemake.input
    stage_vs_thesis(snakemake.config, i.statistics, i.reliability, i.tests, i.pairwise, i.table,
                    snakemake.output.table, snakemake.output.summary)
