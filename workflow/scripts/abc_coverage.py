# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_abc import stage_abc_coverage

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_abc_coverage(snakemake.config, snakemake.wildcards.named, snakemake.input.directions,
                       snakemake.output.replicates, snakemake.output.summary)
