rule table:
    input:
        metrics=all_metrics(),
    output:
        table=report("results/table.csv", caption="../report/table.rst", category="Table 1"),
        wide="results/table_iou.csv",
    log:
        "logs/table.log",
    threads: 1
    resources:
        mem_mb=500,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/table.py"


rule report:
    input:
        table=rules.table.output.table,
        wide=rules.table.output.wide,
        metrics=all_metrics(),
        parts=all_parts_previews(),
    output:
        html="results/report/index.html",
    log:
        "logs/report.log",
    params:
        config=config,
        input_dirs=input_view_dirs(),
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/report.py"
