# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_sequential import stage_sequential_figures

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_sequential_figures(snakemake.config, snakemake.wildcards.named, snakemake.wildcards.dataset,
                             snakemake.input.directions, dict(snakemake.input.items()), dict(snakemake.output.items()))
