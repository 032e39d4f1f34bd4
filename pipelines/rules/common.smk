# Config validation and the helpers that turn the config into targets and parameters.
from snakemake.utils import validate


validate(config, schema="../schemas/config.schema.yaml", set_default=True)

from ipm.methods import METHODS, row_label
from ipm.reference_lines import REFERENCE_LINES

METHOD_ROW = "(?!line_)[A-Za-z0-9_]+_[0-9]+v(_[a-z0-9]+)?"
"""Row ids of methods: the registered name, the number of views and the entry's tag if any,
e.g. visual_hull_12v, ga_1v_labels."""


def row_id(m):
    """The row id of a methods entry (``METHOD_ROW``)."""
    return f"{m['name']}_{m['views']}v" + (f"_{m['tag']}" if m.get("tag") else "")


wildcard_constraints:
    seed="[0-9]+",
    case="[A-Za-z0-9_]+",


def method_cases(m):
    """Cases a methods entry runs on: its own ``cases`` list, else all of the config's."""
    return m.get("cases", config["cases"])


def case_seeds(case):
    """Seeds of a case: its split's ``split_seeds`` entry, else the config's ``seeds``."""
    from ipm.cases import case_split
    from ipm.synth import load_case

    return config["split_seeds"].get(case_split(load_case(case)), config["seeds"])


def method_seeds(m, case):
    """Seeds a methods entry runs on ``case``: its own ``seeds`` list, else the case's; a method
    without random choices (``seeded=False``) runs once, with the first of them."""
    seeds = m.get("seeds", case_seeds(case))
    return seeds if METHODS[m["name"]].seeded else seeds[:1]


def check_methods():
    """Refuse, when the DAG is built, unknown method names, cases outside the config's list and
    generators a method cannot fit (the diff path on trees), each with one line saying why."""
    from ipm.errors import UserError
    from ipm.methods import check_generator
    from ipm.synth import load_case

    from ipm.cases import case_split

    for case in config["cases"]:
        case_split(load_case(case))
    ids = [row_id(m) for m in config["methods"]]
    for rid in ids:
        if ids.count(rid) > 1:
            raise ValueError(f"config: two methods entries make the row {rid}; give one a tag")
    for m in config["methods"]:
        if m["name"] not in METHODS:
            raise ValueError(f"config: unknown method {m['name']!r} (known: {', '.join(METHODS.names())})")
        for case in method_cases(m):
            if case not in config["cases"]:
                raise ValueError(f"config: method {m['name']} lists case {case!r}, which is not in cases")
            if METHODS[m["name"]].uses_generator:
                try:
                    check_generator(m["name"], load_case(case)["generator"])
                except UserError as e:
                    raise ValueError(f"config: case {case}: {e}; give the entry a cases list") from None


check_methods()


def method_of(wildcards):
    """The methods entry of row id ``wildcards.row`` (``diff_1v`` -> {name: diff, views: 1})."""
    for m in config["methods"]:
        if row_id(m) == wildcards.row:
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
        return {"label": REFERENCE_LINES[name].label, "kind": "reference"}
    m = method_of(wildcards)
    kind = "method" if METHODS[m["name"]].uses_generator else "baseline"
    tag = f" [{m['tag']}]" if m.get("tag") else ""
    return {"label": row_label(m["name"], m["views"]) + tag, "kind": kind}


def views_dir(name, views, case):
    """Folder of the rendered views that method ``name`` reads for ``views`` views."""
    return f"results/synth/{case}/{METHODS[name].layout}{views}"


def method_transforms(wildcards):
    m = method_of(wildcards)
    return f"{views_dir(m['name'], m['views'], wildcards.case)}/transforms.json"


def method_inputs(wildcards):
    """Inputs of a reconstruction: its views, and the method's preparation file for the case's
    generator and the run's seed if it has a preparation stage (the GA's gene statistics, made once
    per generator and seed, so the spread over seeds includes theirs; with ``prepare_seed`` set, one
    file made with that seed serves every seed)."""
    m = method_of(wildcards)
    out = {"transforms": method_transforms(wildcards)}
    if METHODS[m["name"]].prepare is not None:
        seed = wildcards.seed if config["prepare_seed"] is None else config["prepare_seed"]
        out["prepared"] = f"results/prepare/{m['name']}/{case_generator(wildcards)}/s{seed}.json"
    return out


def synth_res(wildcards):
    """Reference image size of a view layout (COLMAP's rings are rendered larger, for SIFT)."""
    return config["synth"]["ring_res"] if wildcards.layout == "ring" else config["synth"]["res"]


def input_view_dirs():
    """Per case, the views of the first configured method that runs on it (the report shows its
    view 0)."""
    out = {}
    for m in config["methods"]:
        for case in method_cases(m):
            out.setdefault(case, views_dir(m["name"], m["views"], case))
    return out


def all_metrics():
    """Metrics files of every (row, case, seed): method rows on their cases and seeds, reference
    lines (no random choices) on every case they apply to, with the case's first seed."""
    out = [f"results/evaluate/{row_id(m)}/{case}/s{seed}/metrics.json"
           for m in config["methods"] for case in method_cases(m) for seed in method_seeds(m, case)]
    return out + [f"results/evaluate/line_{name}/{case}/s{case_seeds(case)[0]}/metrics.json"
                  for name in config["reference_lines"] for case in config["cases"] if line_applies(name, case)]


def line_applies(name, case):
    """Whether reference line ``name`` applies to ``case`` (the reseeded truth: stochastic in-family cases)."""
    from ipm.synth import load_case

    return REFERENCE_LINES[name].applies(load_case(case))


def all_parts_previews():
    """Part previews of the rows that fit a generator (baselines have no parts)."""
    return [f"results/reconstruct/{row_id(m)}/{case}/s{seed}/parts.png"
            for m in config["methods"] if METHODS[m["name"]].uses_generator
            for case in method_cases(m) for seed in method_seeds(m, case)]


def get_final_output():
    return ["results/table.csv", "results/table_iou.csv", "results/report/index.html"]
