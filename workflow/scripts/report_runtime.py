# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.runinfo import stage_runtime

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_runtime(snakemake.params.metadata, snakemake.output.jobs, snakemake.output.by_rule,
                  exclude_rules=[snakemake.rule])
