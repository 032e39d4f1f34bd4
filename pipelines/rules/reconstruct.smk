rule prepare:
    output:
        "results/prepare/{method}/{generator}/s{seed}.json",
    log:
        "logs/prepare/{method}/{generator}/s{seed}.log",
    benchmark:
        "logs/benchmark/prepare/{method}/{generator}/s{seed}.tsv"
    # first when it can: every run of its method waits for it (a training started late is the DAG's tail)
    priority: 10
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=RECONSTRUCT_MINUTES[config["profile"]],
    params:
        profile=config["profile"],
    script:
        "../scripts/prepare.py"


rule reconstruct:
    input:
        unpack(method_inputs),
    output:
        run=directory("results/reconstruct/{row}/{case}/s{seed}"),
    log:
        "logs/reconstruct/{row}/{case}/s{seed}.log",
    benchmark:
        "logs/benchmark/reconstruct/{row}/{case}/s{seed}.tsv"
    wildcard_constraints:
        row=METHOD_ROW,
    priority: reconstruct_priority
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        **GPU,
        mem_mb=4000,
        runtime=RECONSTRUCT_MINUTES[config["profile"]],
    params:
        method=method_name,
        n_input_views=method_views,
        generator=case_generator,
        profile=config["profile"],
        settings=lambda wildcards: method_of(wildcards).get("settings", {}),
        device=config["device"],
    script:
        "../scripts/reconstruct.py"


rule reference_line:
    input:
        reference=rules.reference.output.reference,
        truth=rules.reference.output.truth,
    output:
        run=directory("results/reconstruct/line_{name}/{case}/s{seed}"),
    log:
        "logs/reference_line/{name}/{case}/s{seed}.log",
    benchmark:
        "logs/benchmark/reference_line/{name}/{case}/s{seed}.tsv"
    conda:
        "../envs/ipm.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    script:
        "../scripts/reference_line.py"
