# Beyond the thesis (issue 18): simulation-based calibration of the estimators that report an uncertainty.
# Target `calibration` builds every model in config calibration.models; with calibration.in_all the outputs
# also join the default target (the CI config does; the full sizes take hours at today's solver speed).


rule calibration_sbc:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        rows="results/calibration/{named}/sbc_rows.csv",
        summary=report(
            "results/calibration/{named}/sbc_coverage.csv",
            caption="../report/calibration_sbc.rst",
            category="Calibration",
            labels={"model": "{named}", "table": "SBC coverage"},
        ),
        groups="results/calibration/{named}/sbc_coverage_by_group.csv",
    params:
        settings=settings("calibration.checkpoints", "calibration.model_settings.{named}", "calibration.noise",
            "chapter5.bootstrap_direction", "chapter5.eps_D", "chapter5.epsilon", "chapter5.q",
            "chapter5.settings.{named}", "chapter5.sigma_clip", "chapter5.smc.prior_sigma",
            "chapter5.smc.quantile", "chapter5.store_candidates", "chapter6.bin_range_sd", "chapter6.emg_band",
            "chapter6.joint", "chapter6.n_bins", "chapter6.prior_sd_rel", "data.model_dir", "data.thesis_dir",
            "model", "seed"),
    log:
        "logs/calibration/{named}/sbc.log",
    threads: 1
    resources:
        mem_mb=4000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/calibration_sbc.py"


rule calibration_figures:
    input:
        rows="results/calibration/{named}/sbc_rows.csv",
    output:
        ranks=report(
            "results/calibration/{named}/fig_rank_histograms.png",
            caption="../report/calibration_ranks.rst",
            category="Calibration",
            labels={"model": "{named}", "figure": "SBC rank histograms"},
        ),
        coverage=report(
            "results/calibration/{named}/fig_coverage.png",
            caption="../report/calibration_coverage.rst",
            category="Calibration",
            labels={"model": "{named}", "figure": "interval coverage"},
        ),
    log:
        "logs/calibration/{named}/figures.log",
    threads: 1
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/calibration_figures.py"


rule calibration_misfit:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        rows="results/calibration/{named}/misfit_rows.csv",
        summary=report(
            "results/calibration/{named}/misfit_coverage.csv",
            caption="../report/calibration_misfit.rst",
            category="Calibration",
            labels={"model": "{named}", "table": "coverage under misspecification"},
        ),
    params:
        settings=settings("calibration.misfit", "calibration.noise", "chapter6.bin_range_sd", "chapter6.emg_band",
            "chapter6.joint", "chapter6.n_bins", "chapter6.prior_sd_rel", "data.model_dir", "data.thesis_dir",
            "model", "seed"),
    log:
        "logs/calibration/{named}/misfit.log",
    threads: 1
    resources:
        mem_mb=4000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/calibration_misfit.py"


rule calibration:
    input:
        calibration_outputs_list(),
