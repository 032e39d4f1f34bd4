rule reference:
    output:
        reference="results/synth/{case}/reference.ply",
        truth="results/synth/{case}/ground_truth.json",
    log:
        "logs/reference/{case}.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/reference.py"


rule synth:
    output:
        transforms="results/synth/{case}/{layout}{n}/transforms.json",
    log:
        "logs/synth/{case}/{layout}{n}.log",
    benchmark:
        "logs/benchmark/synth/{case}/{layout}{n}.tsv"
    wildcard_constraints:
        layout="hemi|ring",
        n="[0-9]+",
    params:
        views=lambda wildcards: int(wildcards.n),
        res=synth_res,
        spp=config["synth"]["spp"],
    threads: 1
    resources:
        mem_mb=3000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/synth.py"
