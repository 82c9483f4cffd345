# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.mfi.stages import stage_mixed_model

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    o = snakemake.output
    stage_mixed_model(snakemake.config, snakemake.input.data, o.tests, o.fixed, o.random, o.attempts, o.emm,
                      o.pairwise, o.figure)
