# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.report import stage_scorecard
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    o = snakemake.output
    stage_scorecard(snakemake.config, list(snakemake.input), o.table, o.summary, o.tolerances,
                    snakemake.params.tolerances)
