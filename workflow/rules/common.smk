# Config validation, data-set lists and input functions shared by all stages.
import os

from snakemake.exceptions import WorkflowError
from neckstrength.config import ConfigError, check_config_datasets, validate_config

# The config (config/config.yaml merged with any --configfile / --config) is checked as the CLI checks it: an
# unknown key (with the closest valid one suggested) or a value outside its domain stops the run at start-up.
CONFIG_FILES = ["config/config.yaml"] + [os.path.relpath(f) for f in workflow.overwrite_configfiles]
CONFIG_SOURCE = f"config ({', '.join(CONFIG_FILES)})"
try:
    validate_config(config, os.path.join(workflow.current_basedir, "../schemas/config.schema.yaml"), CONFIG_SOURCE)
except ConfigError as exc:
    raise WorkflowError(f"invalid config:\n{exc}") from None


# Validate the input data at start-up: a malformed file stops the run (naming file, row and field)
# before any job starts, so no existing output is removed or overwritten.
from neckstrength.io import DataValidationError, read_activations, read_measurements
from neckstrength.model.geometry import read_point_spec, read_test_points

try:
    read_measurements(config["data"]["measurements"])
    read_activations(config["data"]["activations"])
    if config["geometry"].get("test_points"):
        read_test_points(config["geometry"]["test_points"])
    else:
        read_point_spec(config["geometry"]["test_point_spec"])
    check_config_datasets(config, CONFIG_SOURCE)     # data-set names present in the data (known names listed)
except ConfigError as exc:
    raise WorkflowError(f"invalid config:\n{exc}") from None
except DataValidationError as exc:
    raise WorkflowError(f"invalid input data: {exc}") from None

NAMED_MODELS = list(config["models"])
VARIANT_MODELS = [
    f"{k}-{m}"
    for k in config["variants"]["kinematic"]
    for m in config["variants"]["muscles"]
    if not (k.startswith("p") and m == "sagittal_axial")
]
ALL_MODELS = NAMED_MODELS + [v for v in VARIANT_MODELS if v not in NAMED_MODELS]
MODEL_TABLES = [
    f"{config['data']['model_dir']}/full_model_{t}.csv"
    for t in ("muscles", "moment_arms", "coordinates")
] + [
    f"{config['data']['model_dir']}/b3_implied_strengths.csv"
]
THESIS_TABLES = [
    f"{config['data']['thesis_dir']}/{t}"
    for t in (
        "table_B1_muscles.csv",
        "errata_B1.csv",
        "table_B2_groups_s3m24.csv",
        "table_B4_groups_p3m12.csv",
        "table_B6_groups_p2m7.csv",
        "grouping_supplements.csv",
    )
]


wildcard_constraints:
    model=r"(p2m7|p3m12|s3m24|[sp][732]-(independent|sagittal_axial|sagittal|anatomical))",
    named=r"(p2m7|p3m12|s3m24)",
    kinematic=r"[sp][732]",
    dataset=r"(norm|weak|[A-Za-z][A-Za-z0-9_-]*)",
    muscles=r"(independent|sagittal_axial|sagittal|anatomical)",


def geometry_inputs():
    g = config["geometry"]
    return [g["test_points"]] if g.get("test_points") else [g["test_point_spec"]]


def thesis_param_table(wildcards):
    return {
        "s3m24": f"{config['data']['thesis_dir']}/table_B3_params_s3m24.csv",
        "p3m12": f"{config['data']['thesis_dir']}/table_B5_params_p3m12.csv",
        "p2m7": f"{config['data']['thesis_dir']}/table_B7_params_p2m7.csv",
    }[wildcards.named]


CH4_VARIANTS = VARIANT_MODELS
if config["chapter4"]["reference_variant"] not in CH4_VARIANTS:
    CH4_VARIANTS = CH4_VARIANTS + [config["chapter4"]["reference_variant"]]


def surface_path(variant, kind):
    kinematic, muscles = variant.split("-", 1)
    return f"results/chapter4/{kinematic}/{muscles}/{kind}.csv"


def reference_surface(kind):
    return surface_path(config["chapter4"]["reference_variant"], kind)


def chapter4_surface_inputs(wildcards):
    out = {}
    for v in CH4_VARIANTS:
        out[f"{v}__strength"] = surface_path(v, "strength")
        out[f"{v}__activation"] = surface_path(v, "activation")
    return out


def chapter4_outputs():
    return [
        "results/chapter4/claims.csv",
        "results/chapter4/fig_4_7_kinematic_complexity.png",
        "results/chapter4/fig_4_3_deep_extensor_activation.png",
    ]


CH5_MODELS = list(config["chapter5"]["models"])
CH5_DATASETS = list(config["chapter5"]["datasets"])


def chapter5_dataset_list(wildcards):
    return CH5_DATASETS


def chapter5_estimates(wildcards):
    return [f"results/chapter5/{wildcards.named}/{d}/estimate.csv" for d in CH5_DATASETS]


def chapter5_summaries(wildcards):
    return [f"results/chapter5/{wildcards.named}/{d}/summary.json" for d in CH5_DATASETS]


def chapter5_outputs():
    out = expand("results/chapter5/{named}/table_vs_thesis.csv", named=CH5_MODELS)
    out += expand(
        "results/chapter5/{named}/{dataset}/fig_estimate_traces.png",
        named=CH5_MODELS,
        dataset=CH5_DATASETS,
    )
    out += expand(
        "results/chapter5/{named}/{dataset}/smc_vs_alg4.csv",
        named=CH5_MODELS,
        dataset=[d for d in config["chapter5"]["smc"]["datasets"] if d in CH5_DATASETS],
    )
    out += expand(
        "results/chapter5/{named}/coverage.csv",
        named=config["chapter5"]["coverage"]["models"],
    )
    return out


REPORT_OUTPUTS = [
    "results/report/scorecard.csv",
    "results/report/scorecard_summary.csv",
    "results/report/scorecard_tolerances.csv",
    "results/report/environment.csv",
    "results/report/runtime.csv",
    "results/report/runtime_by_rule.csv",
]


def report_outputs():
    # outputs of workflow/rules/report.smk (included last in the Snakefile)
    return list(REPORT_OUTPUTS)


def scorecard_inputs():
    # the thesis comparison tables among the final outputs of every chapter, as selected by the registry
    # neckstrength.report.scorecard.SOURCES (plus the sibling files its loaders read)
    from neckstrength.report.scorecard import scorecard_inputs as select

    return select([f for f in final_outputs() if f not in REPORT_OUTPUTS])


def runtime_inputs():
    # every other final output: the run-time table is written after all other jobs have finished
    return [f for f in final_outputs() if not f.startswith("results/report/runtime")]


def report_software_versions():
    # a param of the environment rule, so that a changed package version re-runs it
    from neckstrength.report.runinfo import software_versions

    return software_versions()


CH6_MODELS = list(config["chapter6"]["models"])


def chapter6_datasets_for(named):
    return list(config["chapter6"]["model_datasets"].get(named, config["chapter6"]["datasets"]))


def chapter6_dataset_list(wildcards):
    return chapter6_datasets_for(wildcards.named)


def chapter6_estimates(wildcards):
    return [f"results/chapter6/{wildcards.named}/{d}/estimate.csv" for d in chapter6_datasets_for(wildcards.named)]


def chapter6_summaries(wildcards):
    return [f"results/chapter6/{wildcards.named}/{d}/summary.json" for d in chapter6_datasets_for(wildcards.named)]


def chapter6_outputs():
    out = []
    for named in CH6_MODELS:
        out.append(f"results/chapter6/{named}/table_6_1_vs_thesis.csv")
        for d in chapter6_datasets_for(named):
            out.append(f"results/chapter6/{named}/{d}/fig_6_4a_posteriors.png")
    if config["chapter6"]["order_comparison"]["n_participants"] > 0:
        out.append("results/chapter6/order_comparison/orders_vs_random.csv")
    for named in config["chapter6"]["joint"]["models"]:
        for d in chapter6_datasets_for(named):
            out.append(f"results/chapter6/{named}/{d}/joint_estimate.csv")
    for named in config["chapter6"]["criteria_comparison"]["models"]:
        out.append(f"results/chapter6/criteria/{named}/summary.csv")
    return out


GAP_MODELS = list(config["gap"]["models"])
GAP_DATASETS = list(config["gap"]["datasets"])


def gap_measurements():
    return config["gap"].get("measurements") or config["data"]["measurements"]


def gap_dataset_list(wildcards):
    return GAP_DATASETS


def gap_summaries(wildcards):
    return [f"results/gap/{wildcards.model}/{d}/summary.json" for d in GAP_DATASETS]


def gap_effect_tables(wildcards):
    return [f"results/gap/{wildcards.model}/{d}/effects.csv" for d in GAP_DATASETS]


def gap_outputs():
    out = expand("results/gap/{model}/pooled.csv", model=GAP_MODELS)
    out += expand("results/gap/{model}/{dataset}/report.md", model=GAP_MODELS, dataset=GAP_DATASETS)
    out.append(f"results/gap/{config['gap']['benchmark']['model']}/benchmark/confusion.csv")
    return out


def calibration_outputs_list():
    # outputs of workflow/rules/calibration.smk (its rule `calibration` builds them; in `all` with calibration.in_all)
    out = []
    for named in config["calibration"]["models"]:
        out += [f"results/calibration/{named}/{f}" for f in ("sbc_coverage.csv", "fig_rank_histograms.png",
                                                             "fig_coverage.png")]
    for named in config["calibration"].get("misfit", {}).get("models", []):
        out.append(f"results/calibration/{named}/misfit_coverage.csv")
    return out


def clinician_outputs_list():
    # outputs of workflow/rules/clinician.smk (its rule `clinician` builds them; in `all` with clinician.in_all)
    out = []
    for named in config["clinician"]["models"]:
        out += [f"results/clinician/{named}/{f}" for f in ("deficit_summary.csv", "fig_deficit.png")]
        out += [f"results/clinician/{named}/{f}" for f in ("decision_roc.csv", "decision_sequential.csv",
                                                             "decision_reliability.csv", "fig_decision.png")]
    return out


POSTURE_TABLES = [
    f"{config['data']['model_dir']}/postures/{kind}_{p}.csv"
    for p in config["postures"]["postures"]
    for kind in ("moment_arms", "coordinates", "force_length")
] + [f"{config['data']['model_dir']}/postures/postures.csv"]


def postures_outputs():
    # outputs of workflow/rules/postures.smk (issue 20)
    out = []
    for named in config["postures"]["models"]:
        out += [f"results/postures/{named}/{f}" for f in ("summary.csv", "identified.csv", "fig_postures.png",
                                                          "smc.csv")]
    return out


def identifiability_outputs():
    # outputs of workflow/rules/identifiability.smk (issue 31; its rule `identifiability` builds them)
    out = []
    for named in config["identifiability"]["models"]:
        out += [f"results/identifiability/{named}/{f}" for f in ("profiles.csv", "distinguishable.csv",
                                                                 "fig_profiles.png")]
    return out


def reruns_models(chapter):
    # models of the run-to-run distributions: Chapter 5's from reruns.chapter5.models; Table 6.1 is p2m7's
    if chapter == "chapter5":
        return [m for m in config["reruns"]["chapter5"]["models"] if m in config["chapter5"]["models"]]
    return [m for m in ("p2m7",) if m in CH6_MODELS]


def reruns_datasets(chapter, named):
    return list(config["chapter5"]["datasets"]) if chapter == "chapter5" else chapter6_datasets_for(named)


def reruns_member_tables(wildcards):
    return [f"results/reruns/{wildcards.chapter}/{m}/{d}/members.csv" for m in reruns_models(wildcards.chapter)
            for d in reruns_datasets(wildcards.chapter, m)]


def reruns_outputs():
    # outputs of workflow/rules/reruns.smk and the run-to-run scoring (its rule `reruns` builds them; in `all`
    # with reruns.in_all)
    out = [f"results/reruns/{c}/bands.csv" for c in ("chapter5", "chapter6") if reruns_models(c)]
    if config["reruns"]["attribution"]["variants"]:
        out += [f"results/reruns/chapter5/{m}/attribution_summary.csv"
                for m in config["reruns"]["attribution"]["models"] if m in config["chapter5"]["models"]]
    if config["reruns"]["attribution"]["chapter6"]["variants"] and "p2m7" in CH6_MODELS:
        out += ["results/reruns/chapter6/p2m7/attribution_summary.csv"]
    return out + [f"results/report/scorecard_distribution{s}.csv" for s in ("", "_summary", "_spread")]


def reruns_band_tables(wildcards):
    return [f"results/reruns/{c}/bands.csv" for c in ("chapter5", "chapter6") if reruns_models(c)]


def final_outputs():
    out = [
        "results/model/full_model.csv",
        "results/model/momentarm_vs_B1.csv",
        "results/geometry/directions.csv",
        "results/appendix_a/fig_A4_radar.png",
        "results/appendix_a/table_A4.csv",
    ]
    out += expand("results/model/{model}/parameters.csv", model=ALL_MODELS)
    out += expand("results/model/{named}/parameters_vs_thesis.csv", named=NAMED_MODELS)
    out += expand("results/strength/{model}/baseline.csv", model=ALL_MODELS)
    out += chapter4_outputs()
    out += chapter5_outputs()
    if config["gap"]["in_all"]:
        out += gap_outputs()
    out += chapter6_outputs()
    out += chapter3_outputs()
    out += [f"results/trials/{t}/quality_report.md" for t in config.get("trials", {}).get("datasets", {})]
    if config["calibration"]["in_all"]:
        out += calibration_outputs_list()
    out += postures_outputs()
    if config["clinician"]["in_all"]:
        out += clinician_outputs_list()
    if config["identifiability"]["in_all"]:
        out += identifiability_outputs()
    if config["reruns"]["in_all"]:
        out += reruns_outputs()
    out += report_outputs()
    return out


# Every rule declares the config settings it reads (dotted keys, '{wildcard}' filled per job) as
# `params: settings=settings(...)`, so Snakemake reruns exactly the jobs whose settings changed. The script
# hands them to the package as a read-only view that refuses any undeclared key (neckstrength.config.Settings).
from neckstrength.config import select_settings


def settings(*keys):
    def selected(wildcards):
        wc = dict(wildcards.items())
        return select_settings(config, [k.format(**wc) for k in keys])

    return selected


# Trial import (trials.smk): the trial table of one configured trial set.
def trials_table(wildcards):
    tables = config["trials"]["datasets"]
    if wildcards.trialset not in tables:
        raise ValueError(f"no trial table for '{wildcards.trialset}' in config trials.datasets ({', '.join(tables)})")
    return tables[wildcards.trialset]
