# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_gap import stage_gap_pooled

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_gap_pooled(snakemake.config, snakemake.wildcards.model, snakemake.params.datasets,
                     list(snakemake.input.summaries), list(snakemake.input.effects), snakemake.output.table,
                     snakemake.output.ranking)
