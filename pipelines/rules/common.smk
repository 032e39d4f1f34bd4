# Config validation and the helpers that turn the config into targets and parameters.
from snakemake.utils import validate


validate(config, schema="../schemas/config.schema.yaml", set_default=True)

LINE_LABELS = {"convex_hull": "convex hull (reference)", "bounding_sphere": "bounding sphere (reference)"}


def method_rows():
    """Row ids of reconstruction methods, e.g. 'diff_1v', from the config's methods list."""
    return [f"{m['name']}_{m['views']}v" for m in config["methods"]]


def all_rows():
    return method_rows() + [f"line_{name}" for name in config["reference_lines"]]


def method_of(wildcards):
    """The methods entry of row id ``wildcards.row`` (``diff_1v`` -> {name: diff, views: 1})."""
    for m in config["methods"]:
        if f"{m['name']}_{m['views']}v" == wildcards.row:
            return m
    raise ValueError(f"unknown row {wildcards.row}")


def method_name(wildcards):
    return method_of(wildcards)["name"]


def method_views(wildcards):
    return method_of(wildcards)["views"]


def case_generator(wildcards):
    """The generator that reconstructs a case (its 'generator' field)."""
    from ipm.synth import load_case

    return load_case(wildcards.case)["generator"]


def row_info(wildcards):
    """Label and kind of a table row."""
    if wildcards.row.startswith("line_"):
        name = wildcards.row[len("line_"):]
        return {"label": LINE_LABELS[name], "kind": "reference"}
    m = method_of(wildcards)
    views = "view" if m["views"] == 1 else "views"
    return {"label": f"ours ({m['name']}, {m['views']} {views})", "kind": "method"}


def recon_dir(wildcards):
    return f"results/reconstruct/{wildcards.row}/{wildcards.case}"


def all_metrics():
    return expand("results/evaluate/{row}/{case}/metrics.json", row=all_rows(), case=config["cases"])


def all_parts_previews():
    return expand("results/reconstruct/{row}/{case}/parts.png", row=method_rows(), case=config["cases"])


def get_final_output():
    return ["results/table.csv", "results/table_iou.csv", "results/report/index.html"]
