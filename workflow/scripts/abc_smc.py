# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.chapter5 import stage_abc_smc
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    i, o = snakemake.input, snakemake.output
    stage_abc_smc(snakemake.config, snakemake.wildcards.model, snakemake.wildcards.dataset, i.directions,
                  i.estimate, i.summary, o.table, o.generations)
