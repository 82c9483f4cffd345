# Chapter 3: MFI reliability (Fig. 3.2), mixed-model statistics (Fig. 3.3), Table 3.2 and maps (Fig. 3.4),
# and every statistic the thesis reports beside ours. Input: config chapter3.data (per-ROI file, schema in
# docs/chapter3.md) or, when null, a SYNTHETIC cohort drawn with the config seed. Outputs under
# results/chapter3/{dataset}/ with dataset = SYNTHETIC or config chapter3.dataset.
import re

from snakemake.exceptions import WorkflowError
from neckstrength.io import DataValidationError
from neckstrength.mfi import read_mfi
from neckstrength.pipeline.chapter3 import dataset_label, is_synthetic

if not is_synthetic(config):
    try:
        read_mfi(config["chapter3"]["data"])
    except DataValidationError as exc:
        raise WorkflowError(f"invalid chapter3 input data: {exc}") from None

CH3_DATASET = dataset_label(config)
CH3_DATASET_RE = re.escape(CH3_DATASET)
CH3_SYNTHETIC_COHORT = "results/chapter3/SYNTHETIC/mfi_cohort_SYNTHETIC.csv"
# the per-ROI MFI file analysed: the configured file, or the synthetic cohort
CH3_DATA = CH3_SYNTHETIC_COHORT if is_synthetic(config) else config["chapter3"]["data"]
CH3_OUTPUTS = [
    f"results/chapter3/{CH3_DATASET}/{f}"
    for f in (
        "reliability.csv",
        "fig_3_2_reliability.png",
        "mixed_model_tests.csv",
        "fig_3_3_marginal_means.png",
        "table_3_2.csv",
        "fig_3_4_maps.png",
        "thesis_vs_ours.csv",
        "thesis_vs_ours.md",
    )
]
if is_synthetic(config):
    CH3_OUTPUTS.append("results/chapter3/SYNTHETIC/cohort_calibration_SYNTHETIC.csv")
# called by final_outputs() in common.smk (a bound method, so this file defines no functions: snakemake --lint)
chapter3_outputs = CH3_OUTPUTS.copy


rule chapter3_synthetic_cohort:
    input:
        t31=f"{config['data']['thesis_dir']}/table_3_1_demographics.csv",
        t32=f"{config['data']['thesis_dir']}/table_3_2_mfi.csv",
    output:
        cohort=CH3_SYNTHETIC_COHORT,
        calibration=report(
            "results/chapter3/SYNTHETIC/cohort_calibration_SYNTHETIC.csv",
            caption="../report/chapter3_calibration.rst",
            category="Chapter 3",
            subcategory="SYNTHETIC cohort",
            labels={"table": "SYNTHETIC cohort calibration"},
        ),
    params:
        settings=settings("chapter3.loa_multiplier", "chapter3.reliability", "chapter3.synthetic",
            "data.thesis_dir", "seed"),
    log:
        "logs/chapter3/synthetic_cohort.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter3_synthetic_cohort.py"


rule chapter3_reliability:
    input:
        data=CH3_DATA,
    output:
        table=report(
            "results/chapter3/{dataset}/reliability.csv",
            caption="../report/chapter3_reliability.rst",
            category="Chapter 3",
            subcategory="{dataset}: reliability",
            labels={"table": "Bland-Altman and ICC(2,1)"},
        ),
        figure=report(
            "results/chapter3/{dataset}/fig_3_2_reliability.png",
            caption="../report/chapter3_fig_3_2.rst",
            category="Chapter 3",
            subcategory="{dataset}: reliability",
            labels={"figure": "3.2 reliability"},
        ),
    params:
        settings=settings("chapter3.data", "chapter3.loa_multiplier", "chapter3.reliability", "seed"),
    log:
        "logs/chapter3/{dataset}/reliability.log",
    wildcard_constraints:
        dataset=CH3_DATASET_RE,
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter3_reliability.py"


rule chapter3_mixed_model:
    input:
        data=CH3_DATA,
    output:
        tests=report(
            "results/chapter3/{dataset}/mixed_model_tests.csv",
            caption="../report/chapter3_mixed_model.rst",
            category="Chapter 3",
            subcategory="{dataset}: mixed model",
            labels={"table": "Wald tests per effect"},
        ),
        fixed="results/chapter3/{dataset}/mixed_model_fixed_effects.csv",
        random="results/chapter3/{dataset}/mixed_model_random_effects.csv",
        attempts="results/chapter3/{dataset}/mixed_model_fit_attempts.csv",
        emm="results/chapter3/{dataset}/marginal_means.csv",
        pairwise=report(
            "results/chapter3/{dataset}/pairwise_comparisons.csv",
            caption="../report/chapter3_pairwise.rst",
            category="Chapter 3",
            subcategory="{dataset}: mixed model",
            labels={"table": "pairwise group comparisons"},
        ),
        figure=report(
            "results/chapter3/{dataset}/fig_3_3_marginal_means.png",
            caption="../report/chapter3_fig_3_3.rst",
            category="Chapter 3",
            subcategory="{dataset}: mixed model",
            labels={"figure": "3.3 marginal means"},
        ),
    params:
        settings=settings("chapter3.data", "chapter3.mixed_model.emm", "chapter3.mixed_model.random_effects",
            "chapter3.reliability.rater", "seed"),
    log:
        "logs/chapter3/{dataset}/mixed_model.log",
    wildcard_constraints:
        dataset=CH3_DATASET_RE,
    threads: 1
    resources:
        mem_mb=2000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter3_mixed_model.py"


rule chapter3_table_3_2:
    input:
        data=CH3_DATA,
        t32=f"{config['data']['thesis_dir']}/table_3_2_mfi.csv",
    output:
        table=report(
            "results/chapter3/{dataset}/table_3_2.csv",
            caption="../report/chapter3_table_3_2.rst",
            category="Chapter 3",
            subcategory="{dataset}: Table 3.2",
            labels={"table": "3.2 MFI by group, level, quartile"},
        ),
        figure=report(
            "results/chapter3/{dataset}/fig_3_4_maps.png",
            caption="../report/chapter3_fig_3_4.rst",
            category="Chapter 3",
            subcategory="{dataset}: Table 3.2",
            labels={"figure": "3.4 MFI maps"},
        ),
    params:
        settings=settings("chapter3.data", "chapter3.reliability.rater", "data.thesis_dir", "seed"),
    log:
        "logs/chapter3/{dataset}/table_3_2.log",
    wildcard_constraints:
        dataset=CH3_DATASET_RE,
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter3_table_3_2.py"


rule chapter3_vs_thesis:
    input:
        statistics=config["chapter3"]["thesis_statistics"],
        reliability="results/chapter3/{dataset}/reliability.csv",
        tests="results/chapter3/{dataset}/mixed_model_tests.csv",
        pairwise="results/chapter3/{dataset}/pairwise_comparisons.csv",
        table="results/chapter3/{dataset}/table_3_2.csv",
    output:
        table=report(
            "results/chapter3/{dataset}/thesis_vs_ours.csv",
            caption="../report/chapter3_vs_thesis.rst",
            category="Chapter 3",
            subcategory="{dataset}: thesis vs ours",
            labels={"table": "every reported statistic, thesis vs ours"},
        ),
        summary="results/chapter3/{dataset}/thesis_vs_ours.md",
    params:
        settings=settings("chapter3.data", "chapter3.mixed_model.alpha", "seed"),
    log:
        "logs/chapter3/{dataset}/vs_thesis.log",
    wildcard_constraints:
        dataset=CH3_DATASET_RE,
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter3_vs_thesis.py"
