rule prepare:
    output:
        "results/prepare/{method}/{generator}/s{seed}.json",
    log:
        "logs/prepare/{method}/{generator}/s{seed}.log",
    benchmark:
        "logs/benchmark/prepare/{method}/{generator}/s{seed}.tsv"
    params:
        profile=config["profile"],
    threads: 1
    resources:
        mem_mb=3000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/prepare.py"


rule reconstruct:
    input:
        unpack(method_inputs),
    output:
        mesh="results/reconstruct/{row}/{case}/s{seed}/mesh.ply",
        timing="results/reconstruct/{row}/{case}/s{seed}/timing.json",
    log:
        "logs/reconstruct/{row}/{case}/s{seed}.log",
    benchmark:
        "logs/benchmark/reconstruct/{row}/{case}/s{seed}.tsv"
    wildcard_constraints:
        row=METHOD_ROW,
    params:
        method=method_name,
        n_input_views=method_views,
        generator=case_generator,
        profile=config["profile"],
        settings=lambda wildcards: method_of(wildcards).get("settings", {}),
        device=config["device"],
    threads: 1
    resources:
        mem_mb=4000,
        gpu=1 if config["device"] == "cuda" else 0,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/reconstruct.py"


rule reference_line:
    input:
        reference=rules.reference.output.reference,
        truth=rules.reference.output.truth,
    output:
        mesh="results/reconstruct/line_{name}/{case}/s{seed}/mesh.ply",
        timing="results/reconstruct/line_{name}/{case}/s{seed}/timing.json",
    log:
        "logs/reference_line/{name}/{case}/s{seed}.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/reference_line.py"
