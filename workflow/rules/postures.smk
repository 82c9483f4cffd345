# Beyond the thesis (issue 20; its own proposal, Sec. 6.6.2 / 7.1.2.2): posture as a test dimension. One rule
# instance per model of config postures.models: the shipped posture tables checked, neutral-only vs neutral +
# postures on simulated participants (joint sequential estimator), ABC-SMC on mixed tests. docs/postures.md.


rule postures_compare:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        POSTURE_TABLES,
        directions="results/geometry/directions.csv",
    output:
        groups="results/postures/{named}/groups.csv",
        summary=report(
            "results/postures/{named}/summary.csv",
            caption="../report/postures_summary.rst",
            category="Postures (issue 20)",
            labels={"model": "{named}", "table": "error and width per group"},
        ),
        identified="results/postures/{named}/identified.csv",
        picks="results/postures/{named}/picks.csv",
        first_picks="results/postures/{named}/first_picks.csv",
        smc="results/postures/{named}/smc.csv",
        checks="results/postures/{named}/table_checks.csv",
        fig=report(
            "results/postures/{named}/fig_postures.png",
            caption="../report/postures_fig.rst",
            category="Postures (issue 20)",
            labels={"model": "{named}", "figure": "neutral vs postures"},
        ),
        info="results/postures/{named}/summary.json",
    params:
        settings=settings("postures", "chapter6.bin_range_sd", "chapter6.emg_band", "chapter6.joint",
            "chapter6.n_bins", "chapter6.prior_sd_rel", "data", "model", "seed"),
    log:
        "logs/postures/{named}/compare.log",
    threads: 1
    resources:
        mem_mb=4000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/postures_compare.py"
