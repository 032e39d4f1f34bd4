# IPM-Bench: synthetic references -> reconstructions -> 64-view metrics -> table -> report.
# Only wiring here; rules in pipelines/rules, logic in the ipm package.
from snakemake.utils import min_version

min_version("8.0")


configfile: "pipelines/config/default.yaml"


report: "pipelines/report/workflow.rst"


include: "pipelines/rules/common.smk"
include: "pipelines/rules/synth.smk"
include: "pipelines/rules/reconstruct.smk"
include: "pipelines/rules/evaluate.smk"
include: "pipelines/rules/report.smk"


# cheap steps run where Snakemake runs, not as cluster jobs
localrules:
    all,
    reference,
    degrade_masks,
    reference_line,
    table,
    report,
    report_check,


rule all:
    input:
        get_final_output(),
