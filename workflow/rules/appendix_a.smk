# Appendix A: measured strength of the five participants vs the baseline model (Fig. A.4).


rule appendix_a4:
    input:
        measurements=config["data"]["measurements"],
        directions="results/geometry/directions.csv",
        baseline=f"results/strength/{config['appendix_a4']['model']}/baseline.csv",
    output:
        table=report(
            "results/appendix_a/table_A4.csv",
            caption="../report/table_a4.rst",
            category="Appendix A",
            subcategory="strength measurements",
            labels={"table": "A.4 measured vs model"},
        ),
        figure=report(
            "results/appendix_a/fig_A4_radar.png",
            caption="../report/fig_a4.rst",
            category="Appendix A",
            subcategory="strength measurements",
            labels={"figure": "A.4 radar"},
        ),
    params:
        settings=settings("appendix_a4", "data.measurements", "participants"),
    log:
        "logs/appendix_a/a4.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/neckstrength.yaml"
    script:
        "../scripts/appendix_a4.py"
