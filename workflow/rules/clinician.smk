# Beyond the thesis (issue 18 item 4): the clinician loop on the joint posterior. Simulated participants with a
# deep-extensor deficit and normal ones: tests until P(deficit) > p_alarm per strategy, false alarms.
# Target `clinician` builds every model in config clinician.models; with clinician.in_all also part of `all`.


rule clinician_deficit:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        runs="results/clinician/{named}/deficit_runs.csv",
        per_run="results/clinician/{named}/deficit_per_run.csv",
        summary=report(
            "results/clinician/{named}/deficit_summary.csv",
            caption="../report/clinician_deficit.rst",
            category="Clinician loop",
            labels={"model": "{named}", "table": "tests until P(deficit) > 0.9"},
        ),
        fig=report(
            "results/clinician/{named}/fig_deficit.png",
            caption="../report/clinician_deficit.rst",
            category="Clinician loop",
            labels={"model": "{named}", "figure": "P(deficit) by test"},
        ),
    params:
        settings=settings("clinician.deficit", "clinician.session.{named}", "clinician.study",
            "chapter6.bin_range_sd", "chapter6.emg_band", "chapter6.emg_groups.{named}", "chapter6.joint",
            "chapter6.n_bins", "chapter6.prior_sd_rel", "chapter6.n_sim", "chapter6.epsilon", "chapter6.q",
            "chapter6.n_wbins", "chapter6.alpha_min", "chapter6.likelihood", "chapter6.likelihood_floor",
            "chapter6.predictive", "chapter6.n_candidates", "chapter6.model_settings.{named}", "data.model_dir",
            "data.thesis_dir", "geometry.head", "model", "seed"),
    log:
        "logs/clinician/{named}/deficit.log",
    threads: 2    # directions solved concurrently (same numbers for any count)
    resources:
        mem_mb=4000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/clinician_deficit.py"


rule clinician_decision:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        runs="results/clinician/{named}/decision_runs.csv",
        per_run="results/clinician/{named}/decision_per_run.csv",
        rule_grid="results/clinician/{named}/decision_rule_grid.csv",
        calibration="results/clinician/{named}/decision_calibration.csv",
        misfit_guard="results/clinician/{named}/decision_misfit_guard.csv",
        misfit=report(
            "results/clinician/{named}/decision_misfit.csv",
            caption="../report/clinician_decision.rst",
            category="Clinician loop",
            labels={"model": "{named}", "table": "deficit decision: the calibrated misfit guard"},
        ),
        recalibrated=report(
            "results/clinician/{named}/decision_recalibrated.csv",
            caption="../report/clinician_decision.rst",
            category="Clinician loop",
            labels={"model": "{named}", "table": "deficit decision: recalibrated P, held out"},
        ),
        roc=report(
            "results/clinician/{named}/decision_roc.csv",
            caption="../report/clinician_decision.rst",
            category="Clinician loop",
            labels={"model": "{named}", "table": "deficit decision: ROC after t tests"},
        ),
        sequential=report(
            "results/clinician/{named}/decision_sequential.csv",
            caption="../report/clinician_decision.rst",
            category="Clinician loop",
            labels={"model": "{named}", "table": "deficit decision: the stopping rule"},
        ),
        reliability=report(
            "results/clinician/{named}/decision_reliability.csv",
            caption="../report/clinician_decision.rst",
            category="Clinician loop",
            labels={"model": "{named}", "table": "deficit decision: reliability of P(deficit)"},
        ),
        fig=report(
            "results/clinician/{named}/fig_decision.png",
            caption="../report/clinician_decision.rst",
            category="Clinician loop",
            labels={"model": "{named}", "figure": "deficit decision: ROC, reliability, P by test"},
        ),
    params:
        settings=settings("clinician.decision", "clinician.decision_study", "chapter5.settings.{named}",
            "chapter5.epsilon", "chapter5.q", "chapter5.eps_D", "chapter5.sigma_clip", "chapter5.bootstrap_direction",
            "chapter5.store_candidates", "chapter6.bin_range_sd",
            "chapter6.emg_band", "chapter6.emg_groups.{named}", "chapter6.joint", "chapter6.n_bins",
            "chapter6.prior_sd_rel", "data.model_dir", "data.thesis_dir", "model", "postures.force_length",
            "seed"),
    log:
        "logs/clinician/{named}/decision.log",
    threads: 2    # participants in forked processes (same numbers for any count)
    resources:
        mem_mb=3000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/clinician_decision.py"


rule clinician:
    input:
        clinician_outputs_list(),
