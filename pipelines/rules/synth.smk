rule synth:
    output:
        transforms="results/synth/{case}/transforms.json",
        reference="results/synth/{case}/reference.ply",
    log:
        "logs/synth/{case}.log",
    params:
        views=config["synth"]["views"],
        res=config["synth"]["res"],
        spp=config["synth"]["spp"],
    threads: 1
    resources:
        mem_mb=2000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/synth.py"
