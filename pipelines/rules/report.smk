rule table:
    input:
        metrics=all_metrics(),
    output:
        table=report("results/table.csv", caption="../report/table.rst", category="Table 1"),
        wide="results/table_iou.csv",
        summary="results/table_summary.csv",
        markdown="results/table1.md",
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
        summary=rules.table.output.summary,
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
