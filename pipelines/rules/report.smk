rule table:
    input:
        metrics=all_metrics(),
        rows=run_files("results/evaluate/{row}/{case}/s{seed}/row.json"),
    output:
        table=report(
            "results/table.csv",
            caption="../report/table.rst",
            category="Table 1",
        ),
        wide="results/table_iou.csv",
        summary="results/table_summary.csv",
        markdown=report(
            "results/table1.md",
            caption="../report/table1.rst",
            category="Table 1",
        ),
    log:
        "logs/table.log",
    benchmark:
        "logs/benchmark/table.tsv"
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=10,
    params:
        cases=config["cases"],
    script:
        "../scripts/table.py"


rule texture_table:
    input:
        scores=all_texture_scores(),
    output:
        table="results/table_texture.csv",
        markdown=report(
            "results/table_texture.md",
            caption="../report/table_texture.rst",
            category="Table 1",
        ),
    log:
        "logs/texture_table.log",
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=10,
    script:
        "../scripts/texture_table.py"


rule report:
    input:
        **report_inputs(),
        # paths, not rules.table.output: a rule input naming another rule's output makes Snakemake
        # hash the whole input list once per file (the benchmark config's dry run inside the suite:
        # 51 s -> 34 s on the faster kind)
        textures=texture_table_files()[:1],
        table="results/table.csv",
        wide="results/table_iou.csv",
        summary="results/table_summary.csv",
    output:
        html=report(
            "results/report/index.html",
            caption="../report/page.rst",
            category="Report",
        ),
    log:
        "logs/report.log",
    benchmark:
        "logs/benchmark/report.tsv"
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    params:
        config=config,
        input_dirs=input_view_dirs(),
    script:
        "../scripts/report.py"


rule report_check:
    input:
        html=rules.report.output.html,
    output:
        screenshots=directory("results/report/screenshots"),
    log:
        "logs/report_check.log",
    benchmark:
        "logs/benchmark/report_check.tsv"
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=20,
    params:
        rows=lambda wildcards: table_labels(),
    script:
        "../scripts/report_check.py"
