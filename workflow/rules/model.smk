# Foundation stage: full model, test directions, reduced models and their baseline strength.


rule model_full:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
    output:
        table="results/model/full_model.csv",
        compare=report(
            "results/model/momentarm_vs_B1.csv",
            caption="../report/momentarm_vs_b1.rst",
            category="Model",
            subcategory="full model",
            labels={"table": "moment arms vs Table B.1"},
        ),
    params:
        settings=settings("data.model_dir", "data.thesis_dir", "model.apply_b1_errata",
            "model.moment_arm_source", "model.unprinted_strengths", "seed"),
    log:
        "logs/model/full_model.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/model_full.py"


rule model_directions:
    input:
        geometry_inputs(),
    output:
        report(
            "results/geometry/directions.csv",
            caption="../report/directions.rst",
            category="Model",
            subcategory="geometry",
            labels={"table": "test directions"},
        ),
    params:
        settings=settings("geometry"),
    log:
        "logs/geometry/directions.log",
    threads: 1
    resources:
        mem_mb=500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/model_directions.py"


rule model_reduce:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
    output:
        params="results/model/{model}/parameters.csv",
        jacobian="results/model/{model}/jacobian_T.csv",
        groups="results/model/{model}/groups.csv",
    params:
        settings=settings("data.model_dir", "data.thesis_dir", "model", "seed"),
    log:
        "logs/model/{model}/reduce.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/model_reduce.py"


rule model_vs_thesis:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        thesis=thesis_param_table,
    output:
        report(
            "results/model/{named}/parameters_vs_thesis.csv",
            caption="../report/parameters_vs_thesis.rst",
            category="Model",
            subcategory="{named}",
            labels={"model": "{named}", "table": "reduced parameters vs thesis"},
        ),
    params:
        settings=settings("data.model_dir", "data.thesis_dir", "model"),
    log:
        "logs/model/{named}/compare_thesis.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/model_vs_thesis.py"


rule model_baseline_strength:
    input:
        params="results/model/{model}/parameters.csv",
        directions="results/geometry/directions.csv",
    output:
        "results/strength/{model}/baseline.csv",
    params:
        settings=settings("data.model_dir", "data.thesis_dir", "model"),
    log:
        "logs/strength/{model}/baseline.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/model_baseline_strength.py"
