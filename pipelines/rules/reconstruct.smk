rule prepare:
    output:
        "results/prepare/{method}/{generator}.json",
    log:
        "logs/prepare/{method}/{generator}.log",
    params:
        profile=config["profile"],
        seed=config["seed"],
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
        mesh="results/reconstruct/{row}/{case}/mesh.ply",
        timing="results/reconstruct/{row}/{case}/timing.json",
    log:
        "logs/reconstruct/{row}/{case}.log",
    wildcard_constraints:
        row=METHOD_ROW,
    params:
        method=method_name,
        n_input_views=method_views,
        generator=case_generator,
        profile=config["profile"],
        seed=config["seed"],
    threads: 1
    resources:
        mem_mb=4000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/reconstruct.py"


rule reference_line:
    input:
        reference=rules.reference.output.reference,
    output:
        mesh="results/reconstruct/line_{name}/{case}/mesh.ply",
        timing="results/reconstruct/line_{name}/{case}/timing.json",
    log:
        "logs/reference_line/{name}/{case}.log",
    threads: 1
    resources:
        mem_mb=1000,
    conda:
        "../envs/ipm.yaml"
    script:
        "../scripts/reference_line.py"
