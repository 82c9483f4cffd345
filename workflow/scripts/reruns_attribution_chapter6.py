# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.
import sys

from neckstrength.pipeline.common import rule_settings
from neckstrength.pipeline.reruns import reruns_attribution_chapter6
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with open(snakemake.log[0], "w") as log:
    sys.stderr = sys.stdout = log
    reruns_attribution_chapter6(rule_settings(snakemake), snakemake.wildcards.named, snakemake.output.runs,
                                snakemake.output.summary)
