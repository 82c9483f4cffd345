# Sim-to-real gap diagnosis (issue 8; docs/gap_diagnosis.md): per {model} x {dataset} (forces only; Table A.3
# withheld and compared afterwards), a pooled table over the data sets, and the withheld-effect benchmark.


# results/gap/{model}/benchmark/summary.json is the benchmark's, not a data set named 'benchmark'
ruleorder: gap_benchmark > gap_diagnose


rule gap_diagnose:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
        measurements=gap_measurements(),
        noise_table=lambda wildcards: (config["gap"].get("calibration") or {}).get("noise_table") or [],
    output:
        residuals="results/gap/{model}/{dataset}/residuals.csv",
        planes="results/gap/{model}/{dataset}/planes.csv",
        components="results/gap/{model}/{dataset}/components.csv",
        muscles="results/gap/{model}/{dataset}/muscles.csv",
        effects="results/gap/{model}/{dataset}/effects.csv",
        strengths="results/gap/{model}/{dataset}/strengths.csv",
        activation_check="results/gap/{model}/{dataset}/activation_check.csv",
        power="results/gap/{model}/{dataset}/power.csv",
        discrimination="results/gap/{model}/{dataset}/discrimination.csv",
        summary="results/gap/{model}/{dataset}/summary.json",
        report="results/gap/{model}/{dataset}/report.md",
        fig_radar=report(
            "results/gap/{model}/{dataset}/fig_radar.png",
            caption="../report/gap_radar.rst",
            category="Gap diagnosis",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "measured vs model"},
        ),
        fig_where=report(
            "results/gap/{model}/{dataset}/fig_where.png",
            caption="../report/gap_where.rst",
            category="Gap diagnosis",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "where"},
        ),
        fig_effects=report(
            "results/gap/{model}/{dataset}/fig_effects.png",
            caption="../report/gap_effects.rst",
            category="Gap diagnosis",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "which effect"},
        ),
        fig_activation=report(
            "results/gap/{model}/{dataset}/fig_activation.png",
            caption="../report/gap_activation.rst",
            category="Gap diagnosis",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "Table A.3 check"},
        ),
    params:
        settings=settings("chapter5", "data", "gap.bootstrap", "gap.calibration", "gap.discriminate",
            "gap.effect_settings", "gap.effects", "gap.evidence", "gap.fit", "gap.folds", "gap.grid_points",
            "gap.measurements",
            "gap.pair_grid_top", "gap.pairs_top", "gap.penalty", "gap.reach_iter", "gap.reach_samples",
            "gap.refine_iter", "gap.refine_starts", "gap.shoulder_muscles", "gap.start_spread", "gap.starts",
            "gap.tie_sides", "gap.protocols", "geometry.head", "geometry.plane_bands", "model",
            "postures.force_length", "seed"),
    log:
        "logs/gap/{model}/{dataset}/diagnose.log",
    threads: 2   # processes for the calibration's screen of the simulated data sets
    resources:
        mem_mb=3000,   # peak 0.37 GB main, 0.56 GB the largest of its 3 forked workers (s3m24, calibrated, 2 threads,
                       # S003-S007, 2026-11-24 late evening; 4.7 GB main before the solver's slots shrank)
        runtime=60,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/gap_diagnose.py"


rule gap_pooled:
    input:
        summaries=gap_summaries,
        effects=gap_effect_tables,
    output:
        table=report(
            "results/gap/{model}/pooled.csv",
            caption="../report/gap_pooled.rst",
            category="Gap diagnosis",
            subcategory="{model}",
            labels={"model": "{model}", "table": "where / which / how far per data set"},
        ),
        ranking=report(
            "results/gap/{model}/pooled_ranking.csv",
            caption="../report/gap_ranking.rst",
            category="Gap diagnosis",
            subcategory="{model}",
            labels={"model": "{model}", "table": "pooled effect ranking"},
        ),
    params:
        datasets=gap_dataset_list,
    log:
        "logs/gap/{model}/pooled.log",
    threads: 1
    resources:
        mem_mb=500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/gap_pooled.py"


rule gap_benchmark:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        confusion=report(
            "results/gap/{model}/benchmark/confusion.csv",
            caption="../report/gap_benchmark.rst",
            category="Gap diagnosis",
            subcategory="{model}: withheld-effect benchmark",
            labels={"model": "{model}", "table": "confusion matrix"},
        ),
        cases=report(
            "results/gap/{model}/benchmark/cases.csv",
            caption="../report/gap_benchmark_cases.rst",
            category="Gap diagnosis",
            subcategory="{model}: withheld-effect benchmark",
            labels={"model": "{model}", "table": "per case"},
        ),
        accuracy=report(
            "results/gap/{model}/benchmark/accuracy.csv",
            caption="../report/gap_benchmark_accuracy.rst",
            category="Gap diagnosis",
            subcategory="{model}: withheld-effect benchmark",
            labels={"model": "{model}", "table": "accuracy by detectability"},
        ),
        effect_size="results/gap/{model}/benchmark/effect_size.csv",
        report="results/gap/{model}/benchmark/benchmark.md",
        summary="results/gap/{model}/benchmark/summary.json",
    params:
        settings=settings("chapter5.emg_groups.{model}", "chapter5.epsilon", "chapter5.settings.{model}",
            "data.model_dir", "data.thesis_dir", "postures.force_length", "gap.benchmark.bootstrap", "gap.benchmark.calibration",
            "gap.benchmark.chunk", "gap.benchmark.clear_size", "gap.benchmark.controls",
            "gap.benchmark.diagnosis_effects", "gap.benchmark.effects", "gap.benchmark.folds",
            "gap.benchmark.mismatch_replicates", "gap.benchmark.noise_rel", "gap.benchmark.pairs",
            "gap.benchmark.pairs_top", "gap.benchmark.refine_iter", "gap.benchmark.replicates",
            "gap.benchmark.starts", "gap.benchmark.strength_spread",
            "gap.bootstrap", "gap.calibration", "gap.effect_settings", "gap.effects", "gap.fit", "gap.folds",
            "gap.grid_points",
            "gap.pair_grid_top", "gap.pairs_top", "gap.penalty", "gap.reach_iter", "gap.reach_samples",
            "gap.refine_iter", "gap.refine_starts", "gap.shoulder_muscles", "gap.start_spread", "gap.starts",
            "gap.tie_sides", "geometry.head.centre", "model", "seed"),
    log:
        "logs/gap/{model}/benchmark.log",
    threads: 2   # processes: one batch (gap.benchmark.chunk >= cases) shares out its effects' fits; several batches, one each
    resources:
        mem_mb=4000,   # s3m24, 86 cases in one batch: the largest process peaked at 1.3 GB
        runtime=120,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/gap_benchmark.py"


rule gap:
    input:
        gap_outputs(),
