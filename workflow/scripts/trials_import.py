# Thin rule script: reads snakemake.input/output/params and calls one package function.
import sys

from neckstrength.pipeline.trials import trials_import
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    trials_import(snakemake.input.trials, snakemake.input.directions, snakemake.params.settings,
                  snakemake.params.signals, dict(snakemake.output.items()))
