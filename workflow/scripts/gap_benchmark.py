# Thin rule script: reads snakemake.input/output/params and calls the pipeline function of the same name.

from neckstrength.pipeline.common import rule_log, rule_settings
from neckstrength.pipeline.gap import gap_benchmark
from neckstrength.report.runinfo import install_job_record

install_job_record()  # run time and peak memory into the job's log (report)
with rule_log(snakemake):
    gap_benchmark(rule_settings(snakemake), snakemake.wildcards.model, snakemake.input.directions,
                        dict(snakemake.output.items()), workers=snakemake.threads)
