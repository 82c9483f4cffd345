# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.scorecard import stage_scorecard

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    o = snakemake.output
    stage_scorecard(snakemake.config, list(snakemake.input), o.table, o.summary, o.tolerances,
                    snakemake.params.tolerances)
