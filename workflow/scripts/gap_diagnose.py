# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_gap import stage_gap_diagnose

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_gap_diagnose(snakemake.config, snakemake.wildcards.model, snakemake.wildcards.dataset,
                       snakemake.input.directions, dict(snakemake.output.items()))
