# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_compare_thesis_params

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_compare_thesis_params(snakemake.config, snakemake.wildcards.named, snakemake.output[0])
