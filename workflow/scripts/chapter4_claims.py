# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter4 import chapter4_claims
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    inp = snakemake.input
    variants = sorted({k.split("__")[0] for k in inp.keys() if "__" in k})
    surfaces = {v: (inp[f"{v}__strength"], inp[f"{v}__activation"]) for v in variants}
    chapter4_claims(rule_settings(snakemake), surfaces, inp.directions, inp.slopes, snakemake.output[0])
