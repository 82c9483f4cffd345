# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages_sequential_joint import stage_joint_run

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_joint_run(snakemake.config, snakemake.wildcards.named, snakemake.wildcards.dataset,
                    snakemake.input.directions, snakemake.output.iterations, snakemake.output.estimate,
                    snakemake.output.summary)
