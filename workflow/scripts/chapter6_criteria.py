# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_sequential_joint import stage_criteria_comparison

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_criteria_comparison(snakemake.config, snakemake.wildcards.named, snakemake.input.directions,
                              snakemake.output.runs, snakemake.output.summary, snakemake.output.figure)
