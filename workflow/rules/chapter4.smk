# Chapter 4: strength surfaces across kinematic and muscle complexities, deep-extensor scaling.


rule chapter4_surface:
    input:
        MODEL_TABLES,
        THESIS_TABLES,
        directions="results/geometry/directions.csv",
    output:
        strength="results/chapter4/{kinematic}/{muscles}/strength.csv",
        activation="results/chapter4/{kinematic}/{muscles}/activation.csv",
    params:
        settings=settings("chapter4.deep_extensor_group", "chapter4.factors", "chapter4.sweep",
            "data.model_dir", "data.thesis_dir", "model.apply_b1_errata", "model.moment_arm_source",
            "model.signature_tol_m", "model.unprinted_strengths"),
    log:
        "logs/chapter4/{kinematic}/{muscles}/surface.log",
    threads: 1
    resources:
        mem_mb=1500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter4_surface.py"


rule chapter4_reference_figures:
    input:
        directions="results/geometry/directions.csv",
        strength=reference_surface("strength"),
        activation=reference_surface("activation"),
    output:
        slopes=report(
            "results/chapter4/activation_slopes.csv",
            caption="../report/fig_4_5.rst",
            category="Chapter 4",
            subcategory="deep extensors",
            labels={"table": "4.5 activation slopes"},
        ),
        fig43=report(
            "results/chapter4/fig_4_3_deep_extensor_activation.png",
            caption="../report/fig_4_3.rst",
            category="Chapter 4",
            subcategory="deep extensors",
            labels={"figure": "4.3"},
        ),
        fig44=report(
            "results/chapter4/fig_4_4_strength_vs_deep_extensors.png",
            caption="../report/fig_4_4.rst",
            category="Chapter 4",
            subcategory="deep extensors",
            labels={"figure": "4.4"},
        ),
        fig45=report(
            "results/chapter4/fig_4_5_activation_slopes.png",
            caption="../report/fig_4_5.rst",
            category="Chapter 4",
            subcategory="deep extensors",
            labels={"figure": "4.5"},
        ),
        fig46=report(
            "results/chapter4/fig_4_6_activation_1x_vs_0x.png",
            caption="../report/fig_4_6.rst",
            category="Chapter 4",
            subcategory="deep extensors",
            labels={"figure": "4.6a"},
        ),
        fig46b=report(
            "results/chapter4/fig_4_6_activation_1x_vs_0x_b_coronal_posterior.png",
            caption="../report/fig_4_6.rst",
            category="Chapter 4",
            subcategory="deep extensors",
            labels={"figure": "4.6b"},
        ),
    params:
        settings=settings("chapter4.deep_extensor_group", "chapter4.factors", "chapter4.reference_variant",
            "data.model_dir", "data.thesis_dir", "model.apply_b1_errata", "model.moment_arm_source",
            "model.unprinted_strengths"),
    log:
        "logs/chapter4/reference_figures.log",
    threads: 1
    resources:
        mem_mb=1500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter4_reference_figures.py"


rule chapter4_complexity_figures:
    input:
        unpack(chapter4_surface_inputs),
        directions="results/geometry/directions.csv",
    output:
        fig47=report(
            "results/chapter4/fig_4_7_kinematic_complexity.png",
            caption="../report/fig_4_7.rst",
            category="Chapter 4",
            subcategory="model complexity",
            labels={"figure": "4.7"},
        ),
        fig48=report(
            "results/chapter4/fig_4_8_muscle_complexity.png",
            caption="../report/fig_4_8.rst",
            category="Chapter 4",
            subcategory="model complexity",
            labels={"figure": "4.8"},
        ),
    log:
        "logs/chapter4/complexity_figures.log",
    threads: 1
    resources:
        mem_mb=1500,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter4_complexity_figures.py"


rule chapter4_claims:
    input:
        unpack(chapter4_surface_inputs),
        directions="results/geometry/directions.csv",
        slopes="results/chapter4/activation_slopes.csv",
    output:
        report(
            "results/chapter4/claims.csv",
            caption="../report/chapter4_claims.rst",
            category="Chapter 4",
            subcategory="claims",
            labels={"table": "Sec. 4.3-4.4 claims"},
        ),
    params:
        settings=settings("chapter4.anterior_max_azimuth_deg", "chapter4.claim_tolerance_rel",
            "chapter4.reference_variant", "seed"),
    log:
        "logs/chapter4/claims.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/chapter4_claims.py"
