# Chapter 5: ABC strength estimation (Algorithm 4), one rule instance per {model} x {dataset}.


rule chapter5_estimate:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
        measurements=config["data"]["measurements"],
    output:
        estimate="results/chapter5/{model}/{dataset}/estimate.csv",
        history="results/chapter5/{model}/{dataset}/history.csv",
        scores="results/chapter5/{model}/{dataset}/scores.csv",
        dk_hist="results/chapter5/{model}/{dataset}/dk_hist.csv",
        d_by_direction="results/chapter5/{model}/{dataset}/d_by_direction.csv",
        fit="results/chapter5/{model}/{dataset}/fit.csv",
        candidates="results/chapter5/{model}/{dataset}/candidates.csv",
        summary="results/chapter5/{model}/{dataset}/summary.json",
    params:
        settings=settings("chapter5.bootstrap_direction", "chapter5.emg_groups.{model}", "chapter5.eps_D",
            "chapter5.epsilon", "chapter5.participant_emg", "chapter5.participant_emg_band", "chapter5.q",
            "chapter5.settings.{model}", "chapter5.sigma_clip", "chapter5.simulated_emg",
            "chapter5.simulated_emg_band", "chapter5.store_candidates", "data", "model", "seed"),
    log:
        "logs/chapter5/{model}/{dataset}/estimate.log",
    threads: 2
    resources:
        mem_mb=4000,
        runtime=120,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter5_estimate.py"


rule chapter5_figures:
    input:
        directions="results/geometry/directions.csv",
        estimate="results/chapter5/{model}/{dataset}/estimate.csv",
        history="results/chapter5/{model}/{dataset}/history.csv",
        dk_hist="results/chapter5/{model}/{dataset}/dk_hist.csv",
        d_by_direction="results/chapter5/{model}/{dataset}/d_by_direction.csv",
        fit="results/chapter5/{model}/{dataset}/fit.csv",
        candidates="results/chapter5/{model}/{dataset}/candidates.csv",
        summary="results/chapter5/{model}/{dataset}/summary.json",
    output:
        traces=report(
            "results/chapter5/{model}/{dataset}/fig_estimate_traces.png",
            caption="../report/abc_traces.rst",
            category="Chapter 5",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "estimate traces"},
        ),
        dk_hist=report(
            "results/chapter5/{model}/{dataset}/fig_dk_histograms.png",
            caption="../report/abc_dk.rst",
            category="Chapter 5",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "D_k histograms"},
        ),
        d_dir=report(
            "results/chapter5/{model}/{dataset}/fig_d_by_direction.png",
            caption="../report/abc_d_dir.rst",
            category="Chapter 5",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "d by direction"},
        ),
        parallel=report(
            "results/chapter5/{model}/{dataset}/fig_parallel_coordinates.png",
            caption="../report/abc_parallel.rst",
            category="Chapter 5",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "parallel coordinates"},
        ),
        radar=report(
            "results/chapter5/{model}/{dataset}/fig_radar_fit.png",
            caption="../report/abc_radar.rst",
            category="Chapter 5",
            subcategory="{model}",
            labels={"model": "{model}", "dataset": "{dataset}", "figure": "radar fit"},
        ),
    log:
        "logs/chapter5/{model}/{dataset}/figures.log",
    threads: 1
    resources:
        mem_mb=1500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter5_figures.py"


rule chapter5_table:
    input:
        estimates=chapter5_estimates,
        summaries=chapter5_summaries,
    output:
        report(
            "results/chapter5/{named}/table_vs_thesis.csv",
            caption="../report/abc_table.rst",
            category="Chapter 5",
            subcategory="{named}",
            labels={"model": "{named}", "table": "Table 5.x vs thesis"},
        ),
    params:
        settings=settings("data.thesis_dir"),
        datasets=chapter5_dataset_list,
    log:
        "logs/chapter5/{named}/table.log",
    threads: 1
    resources:
        mem_mb=500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter5_table.py"


rule chapter5_smc:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
        estimate="results/chapter5/{model}/{dataset}/estimate.csv",
        summary="results/chapter5/{model}/{dataset}/summary.json",
    output:
        table=report(
            "results/chapter5/{model}/{dataset}/smc_vs_alg4.csv",
            caption="../report/abc_smc.rst",
            category="Chapter 5",
            subcategory="beyond the thesis",
            labels={"model": "{model}", "dataset": "{dataset}", "table": "ABC-SMC vs Algorithm 4"},
        ),
        generations="results/chapter5/{model}/{dataset}/smc_generations.csv",
    params:
        settings=settings("chapter5.bootstrap_direction", "chapter5.emg_groups.{model}", "chapter5.eps_D",
            "chapter5.epsilon", "chapter5.q", "chapter5.settings.{model}", "chapter5.sigma_clip",
            "chapter5.simulated_emg", "chapter5.simulated_emg_band", "chapter5.smc.max_budget",
            "chapter5.smc.n_particles", "chapter5.smc.prior_sigma", "chapter5.smc.quantile",
            "chapter5.store_candidates", "data", "model", "seed"),
    log:
        "logs/chapter5/{model}/{dataset}/smc.log",
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter5_smc.py"


rule chapter5_coverage:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        replicates="results/chapter5/{named}/coverage_replicates.csv",
        summary=report(
            "results/chapter5/{named}/coverage.csv",
            caption="../report/abc_coverage.rst",
            category="Chapter 5",
            subcategory="beyond the thesis",
            labels={"model": "{named}", "table": "posterior coverage"},
        ),
    params:
        settings=settings("chapter5.bootstrap_direction", "chapter5.coverage.noise",
            "chapter5.coverage.replicates", "chapter5.eps_D", "chapter5.epsilon", "chapter5.q",
            "chapter5.settings.{named}", "chapter5.sigma_clip", "chapter5.simulated_emg",
            "chapter5.simulated_emg_band", "chapter5.store_candidates", "data.model_dir", "data.thesis_dir",
            "model", "seed"),
    log:
        "logs/chapter5/{named}/coverage.log",
    threads: 1
    resources:
        mem_mb=2000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter5_coverage.py"
