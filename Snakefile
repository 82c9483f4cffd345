# neckstrength: model-based inference of individual neck muscle strengths (reproduction of the thesis in
# shared/seed). Run: snakemake -c2   (reduced CI config: snakemake -c2 --configfile config/config.ci.yaml)
from snakemake.utils import min_version

min_version("8.20")


configfile: "config/config.yaml"


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/model.smk"
include: "workflow/rules/appendix_a.smk"
include: "workflow/rules/chapter3.smk"
include: "workflow/rules/chapter4.smk"
include: "workflow/rules/chapter5.smk"
include: "workflow/rules/chapter6.smk"
include: "workflow/rules/gap.smk"
include: "workflow/rules/trials.smk"
include: "workflow/rules/calibration.smk"
include: "workflow/rules/postures.smk"
include: "workflow/rules/clinician.smk"
include: "workflow/rules/identifiability.smk"
include: "workflow/rules/reruns.smk"
# keep report.smk the last include: its inputs enumerate the outputs of every chapter above
include: "workflow/rules/report.smk"


rule all:
    input:
        final_outputs(),
    default_target: True
