# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.chapter3 import stage_mixed_model
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    o = snakemake.output
    stage_mixed_model(snakemake.config, snakemake.input.data, o.tests, o.fixed, o.random, o.attempts, o.emm,
                      o.pairwise, o.figure)
