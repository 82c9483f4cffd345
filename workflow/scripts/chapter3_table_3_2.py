# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.chapter3 import chapter3_table_3_2
from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    chapter3_table_3_2(rule_settings(snakemake), snakemake.input.data, snakemake.output.table, snakemake.output.figure)
