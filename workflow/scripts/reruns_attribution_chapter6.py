# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.pipeline.reruns import reruns_attribution_chapter6
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    reruns_attribution_chapter6(rule_settings(snakemake), snakemake.wildcards.named, snakemake.output.runs,
                                snakemake.output.summary)
