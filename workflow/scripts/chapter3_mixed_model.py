# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter3 import chapter3_mixed_model
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    o = snakemake.output
    chapter3_mixed_model(rule_settings(snakemake), snakemake.input.data, o.tests, o.fixed, o.random, o.attempts, o.emm,
                      o.pairwise, o.figure)
