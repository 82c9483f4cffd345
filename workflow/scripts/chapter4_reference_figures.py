# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter4 import chapter4_reference_figures
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    o = snakemake.output
    chapter4_reference_figures(rule_settings(snakemake), snakemake.input.directions, snakemake.input.strength,
                                     snakemake.input.activation, o.slopes, o.fig43, o.fig44, o.fig45, o.fig46)
