# Chapter 6: sequential estimation with entropy-reducing test selection (Algorithms 7-9), one rule instance per
# {named} model x {dataset}; Table 6.1 and the stop points per model; beyond the thesis: orders vs random.


rule chapter6_run:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
        measurements=config["data"]["measurements"],
    output:
        estimate="results/chapter6/{named}/{dataset}/estimate.csv",
        iterations="results/chapter6/{named}/{dataset}/iterations.csv",
        posteriors="results/chapter6/{named}/{dataset}/posteriors.csv",
        expected_dS="results/chapter6/{named}/{dataset}/expected_dS.csv",
        orders="results/chapter6/{named}/{dataset}/orders.csv",
        order_summary="results/chapter6/{named}/{dataset}/order_summary.csv",
        subsets="results/chapter6/{named}/{dataset}/subsets.csv",
        fit="results/chapter6/{named}/{dataset}/fit.csv",
        bins="results/chapter6/{named}/{dataset}/bins.csv",
        summary="results/chapter6/{named}/{dataset}/summary.json",
    params:
        settings=settings("chapter6.alpha_min", "chapter6.bin_range_sd", "chapter6.bins_sensitivity",
            "chapter6.compare_after", "chapter6.emg_band", "chapter6.emg_groups.{named}", "chapter6.epsilon",
            "chapter6.gamma", "chapter6.likelihood", "chapter6.likelihood_floor",
            "chapter6.model_settings.{named}", "chapter6.n_bins", "chapter6.n_candidates",
            "chapter6.n_orders_sampled", "chapter6.n_sim", "chapter6.n_wbins", "chapter6.participant_emg",
            "chapter6.participant_emg_band", "chapter6.predictive", "chapter6.prior_sd_rel", "chapter6.q",
            "chapter6.simulated.{dataset}", "chapter6.simulated_emg", "chapter6.simulated_emg_band",
            "chapter6.stop", "data", "model", "seed"),
    log:
        "logs/chapter6/{named}/{dataset}/run.log",
    threads: 1
    resources:
        mem_mb=6000,
        runtime=60,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter6_run.py"


rule chapter6_figures:
    input:
        directions="results/geometry/directions.csv",
        estimate="results/chapter6/{named}/{dataset}/estimate.csv",
        iterations="results/chapter6/{named}/{dataset}/iterations.csv",
        posteriors="results/chapter6/{named}/{dataset}/posteriors.csv",
        expected_dS="results/chapter6/{named}/{dataset}/expected_dS.csv",
        orders="results/chapter6/{named}/{dataset}/orders.csv",
        fit="results/chapter6/{named}/{dataset}/fit.csv",
        summary="results/chapter6/{named}/{dataset}/summary.json",
    output:
        posteriors=report(
            "results/chapter6/{named}/{dataset}/fig_6_4a_posteriors.png",
            caption="../report/chapter6_posteriors.rst",
            category="Chapter 6",
            subcategory="{dataset}",
            labels={"model": "{named}", "dataset": "{dataset}", "figure": "6.4a/6.5a posterior PDFs"},
        ),
        iterations=report(
            "results/chapter6/{named}/{dataset}/fig_6_4b_estimate_iterations.png",
            caption="../report/chapter6_iterations.rst",
            category="Chapter 6",
            subcategory="{dataset}",
            labels={"model": "{named}", "dataset": "{dataset}", "figure": "6.4b/6.5b/6.10 E and Var"},
        ),
        radar=report(
            "results/chapter6/{named}/{dataset}/fig_6_6_radar_fit.png",
            caption="../report/chapter6_radar.rst",
            category="Chapter 6",
            subcategory="{dataset}",
            labels={"model": "{named}", "dataset": "{dataset}", "figure": "6.6 radar fit"},
        ),
        orders=report(
            "results/chapter6/{named}/{dataset}/fig_6_7_order_entropy.png",
            caption="../report/chapter6_orders.rst",
            category="Chapter 6",
            subcategory="{dataset}",
            labels={"model": "{named}", "dataset": "{dataset}", "figure": "6.7 entropy vs all orders"},
        ),
        expected_dS=report(
            "results/chapter6/{named}/{dataset}/fig_6_8_expected_entropy_reduction.png",
            caption="../report/chapter6_expected_dS.rst",
            category="Chapter 6",
            subcategory="{dataset}",
            labels={"model": "{named}", "dataset": "{dataset}", "figure": "6.8 expected entropy reduction"},
        ),
        stop=report(
            "results/chapter6/{named}/{dataset}/fig_6_9_posterior_stop_vs_all.png",
            caption="../report/chapter6_stop.rst",
            category="Chapter 6",
            subcategory="{dataset}",
            labels={"model": "{named}", "dataset": "{dataset}", "figure": "6.9 posterior after 4 vs 7"},
        ),
    log:
        "logs/chapter6/{named}/{dataset}/figures.log",
    threads: 1
    resources:
        mem_mb=1500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter6_figures.py"


rule chapter6_table:
    input:
        estimates=chapter6_estimates,
        summaries=chapter6_summaries,
    output:
        table=report(
            "results/chapter6/{named}/table_6_1_vs_thesis.csv",
            caption="../report/chapter6_table.rst",
            category="Chapter 6",
            subcategory="Table 6.1",
            labels={"model": "{named}", "table": "Table 6.1 vs thesis"},
        ),
        stop=report(
            "results/chapter6/{named}/stop_points.csv",
            caption="../report/chapter6_stop_points.rst",
            category="Chapter 6",
            subcategory="Table 6.1",
            labels={"model": "{named}", "table": "stop points and late jumps"},
        ),
    params:
        settings=settings("chapter6.thesis_table", "data.thesis_dir"),
        datasets=chapter6_dataset_list,
    log:
        "logs/chapter6/{named}/table.log",
    threads: 1
    resources:
        mem_mb=500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter6_table.py"


rule chapter6_order_comparison:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        table=report(
            "results/chapter6/order_comparison/orders_vs_random.csv",
            caption="../report/chapter6_order_comparison.rst",
            category="Chapter 6",
            subcategory="beyond the thesis",
            labels={"table": "entropy-reducing vs random orders"},
        ),
        figure=report(
            "results/chapter6/order_comparison/fig_orders_vs_random.png",
            caption="../report/chapter6_order_comparison.rst",
            category="Chapter 6",
            subcategory="beyond the thesis",
            labels={"figure": "entropy-reducing vs random orders"},
        ),
    params:
        settings=settings("chapter6.alpha_min", "chapter6.bin_range_sd", "chapter6.emg_band",
            "chapter6.emg_groups", "chapter6.epsilon", "chapter6.likelihood", "chapter6.likelihood_floor",
            "chapter6.model_settings", "chapter6.n_bins", "chapter6.n_candidates", "chapter6.n_sim",
            "chapter6.n_wbins", "chapter6.order_comparison", "chapter6.predictive", "chapter6.prior_sd_rel",
            "chapter6.q", "chapter6.simulated_emg", "chapter6.simulated_emg_band", "data.model_dir",
            "data.thesis_dir", "model", "seed"),
    log:
        "logs/chapter6/order_comparison.log",
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter6_order_comparison.py"


rule chapter6_joint:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
        measurements=config["data"]["measurements"],
    output:
        iterations="results/chapter6/{named}/{dataset}/joint_iterations.csv",
        estimate=report(
            "results/chapter6/{named}/{dataset}/joint_estimate.csv",
            caption="../report/chapter6_joint.rst",
            category="Chapter 6",
            subcategory="beyond the thesis",
            labels={"model": "{named}", "data set": "{dataset}", "table": "joint posterior estimate"},
        ),
        summary="results/chapter6/{named}/{dataset}/joint_summary.json",
    params:
        settings=settings("chapter6.bin_range_sd", "chapter6.emg_band", "chapter6.emg_groups.{named}",
            "chapter6.joint", "chapter6.n_bins", "chapter6.participant_emg", "chapter6.participant_emg_band",
            "chapter6.prior_sd_rel", "chapter6.simulated.{dataset}", "chapter6.simulated_emg",
            "chapter6.simulated_emg_band", "data", "model", "seed"),
    log:
        "logs/chapter6/{named}/{dataset}/joint.log",
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter6_joint.py"


rule chapter6_criteria:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        runs="results/chapter6/criteria/{named}/runs.csv",
        summary=report(
            "results/chapter6/criteria/{named}/summary.csv",
            caption="../report/chapter6_criteria.rst",
            category="Chapter 6",
            subcategory="beyond the thesis",
            labels={"model": "{named}", "table": "test-selection criteria"},
        ),
        figure=report(
            "results/chapter6/criteria/{named}/fig_criteria.png",
            caption="../report/chapter6_criteria.rst",
            category="Chapter 6",
            subcategory="beyond the thesis",
            labels={"model": "{named}", "figure": "test-selection criteria"},
        ),
    params:
        settings=settings("chapter6.alpha_min", "chapter6.bin_range_sd", "chapter6.criteria_comparison",
            "chapter6.emg_band", "chapter6.epsilon", "chapter6.joint", "chapter6.likelihood",
            "chapter6.likelihood_floor", "chapter6.model_settings.{named}", "chapter6.n_bins",
            "chapter6.n_candidates", "chapter6.n_sim", "chapter6.n_wbins", "chapter6.predictive",
            "chapter6.prior_sd_rel", "chapter6.q", "data.model_dir", "data.thesis_dir", "model", "seed"),
    log:
        "logs/chapter6/criteria/{named}.log",
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter6_criteria.py"
