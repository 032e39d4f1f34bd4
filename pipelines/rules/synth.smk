rule reference:
    output:
        reference="results/synth/{case}/reference.ply",
        truth="results/synth/{case}/ground_truth.json",
        gallery=report(
            "results/synth/{case}/gallery.png",
            caption="../report/gallery.rst",
            category="Gallery",
            subcategory="{case}",
            labels={"case": "{case}", "row": "reference", "seed": "-"},
        ),
        masks="results/synth/{case}/reference_masks.npz",
    log:
        "logs/reference/{case}.log",
    benchmark:
        "logs/benchmark/reference/{case}.tsv"
    # before the reconstructions (as every view set): short, and every later job needs one
    priority: 4
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        n_views=config["evaluate"]["views"],
        res=config["evaluate"]["res"],
    script:
        "../scripts/reference.py"


rule synth:
    output:
        views=directory("results/synth/{case}/{layout}{n}"),
    log:
        "logs/synth/{case}/{layout}{n}.log",
    benchmark:
        "logs/benchmark/synth/{case}/{layout}{n}.tsv"
    # before the reconstructions: short jobs every later one waits for; a view set rendered late
    # makes a chain (views, baseline, evaluation) that ends the run with one core idle
    priority: 4
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        views=lambda wildcards: int(wildcards.n),
        res=synth_res,
        spp=config["synth"]["spp"],
    script:
        "../scripts/synth.py"


rule degrade_masks:
    input:
        views="results/synth/{case}/{layout}{n}",
    output:
        views=directory("results/synth/{case}/{layout}{n}_mask{mask}"),
    log:
        "logs/degrade_masks/{case}/{layout}{n}_mask{mask}.log",
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        seed=config["mask_seed"],
    script:
        "../scripts/degrade_masks.py"
