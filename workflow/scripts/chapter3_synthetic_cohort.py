# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.mfi.stages import stage_synthetic_cohort

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    stage_synthetic_cohort(snakemake.config, snakemake.output.cohort, snakemake.output.calibration)
