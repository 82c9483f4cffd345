# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.stages import stage_chapter4_reference_figures

with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    o = snakemake.output
    stage_chapter4_reference_figures(snakemake.config, snakemake.input.directions, snakemake.input.strength,
                                     snakemake.input.activation, o.slopes, o.fig43, o.fig44, o.fig45, o.fig46)
