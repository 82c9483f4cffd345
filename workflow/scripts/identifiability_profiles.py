# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.pipeline.identifiability import identifiability_profiles
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    o = snakemake.output
    identifiability_profiles(rule_settings(snakemake), snakemake.wildcards.named, snakemake.input.directions,
                             o.profiles, o.distinguishable, o.fig)
