# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.chapter4 import stage_chapter4_reference_figures
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    o = snakemake.output
    stage_chapter4_reference_figures(snakemake.config, snakemake.input.directions, snakemake.input.strength,
                                     snakemake.input.activation, o.slopes, o.fig43, o.fig44, o.fig45, o.fig46)
