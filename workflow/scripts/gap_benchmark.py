# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_gap import stage_gap_benchmark

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_gap_benchmark(snakemake.config, snakemake.wildcards.model, snakemake.input.directions,
                        dict(snakemake.output.items()))
