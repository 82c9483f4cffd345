# Trial import (issue 19; docs/trials.md): a lab's trial table -> max-force and activation tables in the
# Table A.2 / A.3 layouts, plus a quality report (direction matching, repeat rule, fatigue, every exclusion).
# Trial tables: config trials.datasets {name: file}; settings: config trials.settings.


rule trials_import:
    input:
        trials=trials_table,
        directions="results/geometry/directions.csv",
    output:
        max_force="results/trials/{trialset}/max_force.csv",
        activation="results/trials/{trialset}/activation.csv",
        activation_by_muscle="results/trials/{trialset}/activation_by_muscle.csv",
        trials="results/trials/{trialset}/quality_trials.csv",
        exclusions="results/trials/{trialset}/exclusions.csv",
        fatigue="results/trials/{trialset}/fatigue.csv",
        noise="results/trials/{trialset}/noise.csv",
        report="results/trials/{trialset}/quality_report.md",
        figure=report(
            "results/trials/{trialset}/fig_quality.png",
            caption="../report/trials_quality.rst",
            category="Trial import",
            subcategory="{trialset}",
            labels={"trial set": "{trialset}", "figure": "quality"},
        ),
        summary="results/trials/{trialset}/summary.json",
    params:
        settings=settings("trials.settings", "trials.signals.{trialset}"),
    wildcard_constraints:
        trialset=r"[A-Za-z][A-Za-z0-9_-]*",
    log:
        "logs/trials/{trialset}/trials_import.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/trials_import.py"
