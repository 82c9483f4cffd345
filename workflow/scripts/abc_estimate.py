# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_abc import stage_abc_estimate

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_abc_estimate(snakemake.config, snakemake.wildcards.model, snakemake.wildcards.dataset,
                       snakemake.input.directions, dict(snakemake.output.items()), snakemake.threads)
