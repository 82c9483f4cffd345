# Beyond the thesis (issue 31 item 1): identifiability profiles. One rule instance per model of config
# identifiability.models: the best achievable misfit with one group fixed and the others free within bounds, and the
# noise level below which a deficit of the deep extensors is distinguishable. docs/identifiability.md.


rule identifiability_profiles:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        POSTURE_TABLES,
        directions="results/geometry/directions.csv",
    output:
        profiles=report(
            "results/identifiability/{named}/profiles.csv",
            caption="../report/identifiability.rst",
            category="Identifiability (issue 31)",
            labels={"model": "{named}", "table": "misfit profiles"},
        ),
        distinguishable=report(
            "results/identifiability/{named}/distinguishable.csv",
            caption="../report/identifiability.rst",
            category="Identifiability (issue 31)",
            labels={"model": "{named}", "table": "noise level sigma*"},
        ),
        fig=report(
            "results/identifiability/{named}/fig_profiles.png",
            caption="../report/identifiability.rst",
            category="Identifiability (issue 31)",
            labels={"model": "{named}", "figure": "misfit profiles"},
        ),
    params:
        settings=settings("identifiability", "postures.postures", "postures.force_length", "data", "model", "seed"),
    log:
        "logs/identifiability/{named}/profiles.log",
    threads: 1
    resources:
        mem_mb=3000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/identifiability_profiles.py"


rule identifiability:
    input:
        identifiability_outputs(),
