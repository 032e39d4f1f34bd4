rule evaluate:
    input:
        reference=rules.reference.output.reference,
        truth=rules.reference.output.truth,
        mesh="results/reconstruct/{row}/{case}/s{seed}/mesh.ply",
        timing="results/reconstruct/{row}/{case}/s{seed}/timing.json",
    output:
        metrics="results/evaluate/{row}/{case}/s{seed}/metrics.json",
        row="results/evaluate/{row}/{case}/s{seed}/row.json",
        preview=report(
            "results/evaluate/{row}/{case}/s{seed}/preview.png",
            caption="../report/preview.rst",
            category="Silhouettes",
            subcategory="{case}",
            labels={"case": "{case}", "row": "{row}", "seed": "{seed}"},
        ),
    log:
        "logs/evaluate/{row}/{case}/s{seed}.log",
    benchmark:
        "logs/benchmark/evaluate/{row}/{case}/s{seed}.tsv"
    params:
        row=row_info,
        n_views=config["evaluate"]["views"],
        res=config["evaluate"]["res"],
        grid=config["evaluate"]["grid"],
    threads: 1
    resources:
        mem_mb=3000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/evaluate.py"


rule parts_preview:
    input:
        reference=rules.reference.output.reference,
        transforms=method_transforms,
        mesh="results/reconstruct/{row}/{case}/s{seed}/mesh.ply",
    output:
        png=report(
            "results/reconstruct/{row}/{case}/s{seed}/parts.png",
            caption="../report/parts.rst",
            category="Part-labelled meshes",
            subcategory="{case}",
            labels={"case": "{case}", "row": "{row}", "seed": "{seed}"},
        ),
    log:
        "logs/parts_preview/{row}/{case}/s{seed}.log",
    wildcard_constraints:
        row=METHOD_ROW,
    threads: 1
    resources:
        mem_mb=2000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/parts_preview.py"
