# Thin rule script: reads snakemake.input/output/config and calls one package function.
import sys

from neckstrength.pipeline.chapter4 import stage_chapter4_claims
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    inp = snakemake.input
    variants = sorted({k.split("__")[0] for k in inp.keys() if "__" in k})
    surfaces = {v: (inp[f"{v}__strength"], inp[f"{v}__activation"]) for v in variants}
    stage_chapter4_claims(snakemake.config, surfaces, inp.directions, inp.slopes, snakemake.output[0])
