# Run-to-run distributions (issue 36): each stochastic thesis result rerun with K independent random streams, one
# rule instance per chapter x model x data set; the printed cells beside our central band per chapter. The scoring
# (thesis value inside our band or not, with the test's chance rate) is rule report_distribution (report.smk).


rule reruns_members:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
        measurements=config["data"]["measurements"],
    output:
        "results/reruns/{chapter}/{named}/{dataset}/members.csv",
    params:
        settings=settings("{chapter}", "data", "model", "reruns.{chapter}", "reruns.level", "seed"),
    wildcard_constraints:
        chapter=r"chapter[56]",
    log:
        "logs/reruns/{chapter}/{named}/{dataset}/members.log",
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/reruns_members.py"


rule reruns_bands:
    input:
        reruns_member_tables,
    output:
        report(
            "results/reruns/{chapter}/bands.csv",
            caption="../report/reruns_bands.rst",
            category="Scorecard",
            subcategory="run-to-run",
            labels={"table": "{chapter}: our central band per printed cell"},
        ),
    params:
        settings=settings("chapter6.thesis_table", "data.thesis_dir", "reruns.level", "seed"),
    wildcard_constraints:
        chapter=r"chapter[56]",
    log:
        "logs/reruns/{chapter}/bands.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/reruns_bands.py"


rule reruns:
    # target: the run-to-run distributions and their scoring (`snakemake -c2 reruns`)
    input:
        reruns_outputs(),


rule reruns_attribution:
    # Chapter 5 rerun with one input changed at a time (reruns.attribution.variants): which input moves our value
    # onto the thesis's
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        geometry_inputs(),
        measurements=config["data"]["measurements"],
    output:
        runs="results/reruns/chapter5/{named}/attribution.csv",
        summary=report(
            "results/reruns/chapter5/{named}/attribution_summary.csv",
            caption="../report/reruns_attribution.rst",
            category="Scorecard",
            subcategory="run-to-run",
            labels={"table": "{named}: Chapter 5 with one input changed at a time"},
        ),
    params:
        settings=settings("chapter5", "data", "geometry", "model", "models", "reruns.attribution.models",
            "reruns.attribution.variants", "reruns.level", "seed"),
    log:
        "logs/reruns/chapter5/{named}/attribution.log",
    threads: 1
    resources:
        mem_mb=4000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/reruns_attribution.py"


rule reruns_attribution_chapter6:
    # Table 6.1 rerun with one input changed at a time (reruns.attribution.chapter6), K members per variant and
    # data set: which input moves our distribution onto the thesis's value
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        geometry_inputs(),
        measurements=config["data"]["measurements"],
    output:
        runs="results/reruns/chapter6/{named}/attribution.csv",
        summary=report(
            "results/reruns/chapter6/{named}/attribution_summary.csv",
            caption="../report/reruns_attribution.rst",
            category="Scorecard",
            subcategory="run-to-run",
            labels={"table": "{named}: Table 6.1 with one input changed at a time"},
        ),
    params:
        settings=settings("chapter5", "chapter6", "data", "geometry", "model", "models", "reruns.attribution.chapter6",
            "reruns.chapter6.n_candidates", "reruns.level", "seed"),
    wildcard_constraints:
        named="p2m7",
    log:
        "logs/reruns/chapter6/{named}/attribution.log",
    threads: 1
    resources:
        mem_mb=4000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/reruns_attribution_chapter6.py"
