# Config validation and the helpers that turn the config into targets and parameters.
from snakemake.utils import validate


validate(config, schema="../schemas/config.schema.yaml", set_default=True)

from ipm.methods import METHODS, row_label

METHOD_ROW = "(?!line_)[A-Za-z0-9_]+_[0-9]+v"
"""Row ids of methods: the registered name and the number of views, e.g. visual_hull_12v."""
LINE_LABELS = {"convex_hull": "convex hull (reference)", "bounding_sphere": "bounding sphere (reference)"}


def method_rows():
    """Row ids of reconstruction methods, e.g. 'diff_1v', from the config's methods list."""
    return [f"{m['name']}_{m['views']}v" for m in config["methods"]]


def all_rows():
    return method_rows() + [f"line_{name}" for name in config["reference_lines"]]


def check_methods():
    """Refuse unknown method names when the DAG is built, with the known ones in the message."""
    for m in config["methods"]:
        if m["name"] not in METHODS:
            raise ValueError(f"config: unknown method {m['name']!r} (known: {', '.join(METHODS.names())})")


check_methods()


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
    """Label and kind of a table row: ours ("method", takes a generator), a baseline, a reference line."""
    if wildcards.row.startswith("line_"):
        name = wildcards.row[len("line_"):]
        return {"label": LINE_LABELS[name], "kind": "reference"}
    m = method_of(wildcards)
    kind = "method" if METHODS[m["name"]].uses_generator else "baseline"
    return {"label": row_label(m["name"], m["views"]), "kind": kind}


def views_dir(name, views, case):
    """Folder of the rendered views that method ``name`` reads for ``views`` views."""
    return f"results/synth/{case}/{METHODS[name].layout}{views}"


def method_transforms(wildcards):
    m = method_of(wildcards)
    return f"{views_dir(m['name'], m['views'], wildcards.case)}/transforms.json"


def synth_res(wildcards):
    """Reference image size of a view layout (COLMAP's rings are rendered larger, for SIFT)."""
    return config["synth"]["ring_res"] if wildcards.layout == "ring" else config["synth"]["res"]


def input_view_dirs():
    """Per case, the views of the first configured method (the report shows its view 0)."""
    m = config["methods"][0]
    return {case: views_dir(m["name"], m["views"], case) for case in config["cases"]}


def recon_dir(wildcards):
    return f"results/reconstruct/{wildcards.row}/{wildcards.case}"


def all_metrics():
    return expand("results/evaluate/{row}/{case}/metrics.json", row=all_rows(), case=config["cases"])


def all_parts_previews():
    """Part previews of the rows that fit a generator (baselines have no parts)."""
    rows = [f"{m['name']}_{m['views']}v" for m in config["methods"] if METHODS[m["name"]].uses_generator]
    return expand("results/reconstruct/{row}/{case}/parts.png", row=rows, case=config["cases"])


def get_final_output():
    return ["results/table.csv", "results/table_iou.csv", "results/report/index.html"]
