# Report: the thesis scorecard (every printed number we reproduce, ours beside it, with a verdict), run time and
# peak memory per job from the run's own records, software versions and seeds. Included LAST in the Snakefile:
# the input functions (common.smk) enumerate the outputs of every chapter included before.


rule report_scorecard:
    input:
        scorecard_inputs(),
    output:
        table=report(
            "results/report/scorecard.csv",
            caption="../report/scorecard.rst",
            category="Scorecard",
            subcategory="thesis vs ours",
            labels={"table": "scorecard (every item)"},
        ),
        summary=report(
            "results/report/scorecard_summary.csv",
            caption="../report/scorecard_summary.rst",
            category="Scorecard",
            subcategory="thesis vs ours",
            labels={"table": "summary per chapter"},
        ),
        tolerances=report(
            "results/report/scorecard_tolerances.csv",
            caption="../report/scorecard_tolerances.rst",
            category="Scorecard",
            subcategory="thesis vs ours",
            labels={"table": "tolerances and their reasons"},
        ),
    params:
        settings=settings("chapter3.mixed_model.alpha", "chapter4", "chapter5.eps_D", "chapter5.sigma_clip",
            "data.model_dir", "data.thesis_dir", "model", "seed"),
        tolerances=config["report"]["tolerances"],
    log:
        "logs/report/scorecard.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/report_scorecard.py"


rule report_environment:
    output:
        report(
            "results/report/environment.csv",
            caption="../report/environment.rst",
            category="Run records",
            subcategory="software and seeds",
            labels={"table": "software versions and seeds"},
        ),
    params:
        settings=settings("chapter3.data", "chapter5.datasets", "chapter5.models", "seed"),
        seed=config["seed"],
        software=report_software_versions(),
    log:
        "logs/report/environment.log",
    threads: 1
    resources:
        mem_mb=500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/report_environment.py"


rule report_runtime:
    input:
        runtime_inputs(),
    output:
        jobs=report(
            "results/report/runtime.csv",
            caption="../report/runtime.rst",
            category="Run records",
            subcategory="run time and memory",
            labels={"table": "per job"},
        ),
        by_rule=report(
            "results/report/runtime_by_rule.csv",
            caption="../report/runtime.rst",
            category="Run records",
            subcategory="run time and memory",
            labels={"table": "per rule"},
        ),
    params:
        metadata=".snakemake/metadata",
    log:
        "logs/report/runtime.log",
    threads: 1
    resources:
        mem_mb=500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/report_runtime.py"


rule report_distribution:
    # run-to-run scoring (issue 36): each printed Chapter 5 / 6 value against our central band (reruns.smk)
    input:
        bands=reruns_band_tables,
        scorecard="results/report/scorecard.csv",
    output:
        table=report(
            "results/report/scorecard_distribution.csv",
            caption="../report/scorecard_distribution.rst",
            category="Scorecard",
            subcategory="run-to-run",
            labels={"table": "every Chapter 5 / 6 item against our band"},
        ),
        summary=report(
            "results/report/scorecard_distribution_summary.csv",
            caption="../report/scorecard_distribution.rst",
            category="Scorecard",
            subcategory="run-to-run",
            labels={"table": "share inside our band per table"},
        ),
        spread=report(
            "results/report/scorecard_distribution_spread.csv",
            caption="../report/scorecard_distribution.rst",
            category="Scorecard",
            subcategory="run-to-run",
            labels={"table": "seed-to-seed spread per muscle group"},
        ),
    params:
        settings=settings("reruns.level", "seed"),
    log:
        "logs/report/distribution.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/report_distribution.py"
