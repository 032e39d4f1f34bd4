rule evaluate:
    input:
        reference=rules.reference.output.reference,
        reference_masks=rules.reference.output.masks,
        truth=rules.reference.output.truth,
        run="results/reconstruct/{row}/{case}/s{seed}",
        views=recovery_views,
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
        gallery=report(
            "results/evaluate/{row}/{case}/s{seed}/gallery.png",
            caption="../report/gallery.rst",
            category="Gallery",
            subcategory="{case}",
            labels={"case": "{case}", "row": "{row}", "seed": "{seed}"},
        ),
    log:
        "logs/evaluate/{row}/{case}/s{seed}.log",
    benchmark:
        "logs/benchmark/evaluate/{row}/{case}/s{seed}.tsv"
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        row=row_info,
        n_views=config["evaluate"]["views"],
        res=config["evaluate"]["res"],
        grid=config["evaluate"]["grid"],
    script:
        "../scripts/evaluate.py"


rule parts_preview:
    input:
        reference=rules.reference.output.reference,
        views=method_views_dir,
        run="results/reconstruct/{row}/{case}/s{seed}",
    output:
        png=report(
            "results/evaluate/{row}/{case}/s{seed}/parts.png",
            caption="../report/parts.rst",
            category="Part-labelled meshes",
            subcategory="{case}",
            labels={"case": "{case}", "row": "{row}", "seed": "{seed}"},
        ),
    log:
        "logs/parts_preview/{row}/{case}/s{seed}.log",
    benchmark:
        "logs/benchmark/parts_preview/{row}/{case}/s{seed}.tsv"
    wildcard_constraints:
        row=METHOD_ROW,
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/parts_preview.py"


rule texture:
    input:
        run="results/reconstruct/{row}/{case}/s{seed}",
        views=texture_views_dir,
    output:
        scores="results/evaluate/{row}/{case}/s{seed}/texture.json",
    log:
        "logs/texture/{row}/{case}/s{seed}.log",
    benchmark:
        "logs/benchmark/texture/{row}/{case}/s{seed}.tsv"
    wildcard_constraints:
        row=METHOD_ROW,
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        row=row_info,
        n_input=method_views,
        appearance=method_appearance,
    script:
        "../scripts/texture.py"
