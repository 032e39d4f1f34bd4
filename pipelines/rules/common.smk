# Config validation and the helpers that turn the config into targets and parameters.
import functools

from snakemake.utils import validate

validate(config, schema="../schemas/config.schema.yaml", set_default=True)

from ipm.cases import expand_groups

config.update(expand_groups(config))  # a group's name in a cases list stands for its cases

from ipm.methods import METHODS, row_label
from ipm.reference_lines import REFERENCE_LINES

from ipm.table import ROW_ID as METHOD_ROW, row_id


wildcard_constraints:
    seed="[0-9]+",
    case="[A-Za-z0-9_]+",
    row="[A-Za-z0-9_]+",
    name="[a-z0-9_]+",
    method="[a-z0-9_]+",
    generator="[a-z0-9_]+",
    layout="hemi|ring|photo|held",
    n="[0-9]+",
    mask="[a-z0-9]+",


def method_cases(m):
    """Cases a methods entry runs on: those of its own ``cases`` list that the config's ``cases``
    has (so ``--config 'cases=[cup_1]'`` narrows every row), else all of the config's.
    """
    return [c for c in m.get("cases", config["cases"]) if c in config["cases"]]


def case_seeds(case):
    """Seeds of a case: its split's ``split_seeds`` entry, else the config's ``seeds``."""
    from ipm.cases import case_split, load_case

    return config["split_seeds"].get(case_split(load_case(case)), config["seeds"])


def method_seeds(m, case):
    """Seeds a methods entry runs on ``case``: its own ``seeds`` list (or its list for ``case``
    where ``seeds`` maps cases to lists), else the case's; a method without random choices
    (``seeded=False``) runs once, with the first of them."""
    seeds = m.get("seeds", case_seeds(case))
    if isinstance(seeds, dict):
        seeds = seeds.get(case, case_seeds(case))
    return seeds if METHODS[m["name"]].seeded else seeds[:1]


def check_methods():
    """Refuse, when the DAG is built, unknown method names, unknown case names in a row's list and
    generators a method cannot fit (the diff path on trees), each with one line saying why.
    """
    from ipm.cases import case_split, load_case
    from ipm.errors import UserError
    from ipm.methods import check_generator

    for case in config["cases"]:
        case_split(load_case(case))
    if config["prepared"] == "shipped" and config["profile"] != "default":
        raise ValueError(
            f"config: prepared: shipped are the default profile's preparations; profile "
            f"{config['profile']} trains its own (prepared: run)"
        )
    ids = [row_id(m) for m in config["methods"]]
    for rid in ids:
        if ids.count(rid) > 1:
            raise ValueError(f"config: two methods entries make the row {rid}; give one a tag")
    for m in config["methods"]:
        if m["name"] not in METHODS:
            raise ValueError(f"config: unknown method {m['name']!r} (known: {', '.join(METHODS.names())})")
        if m.get("mask") is not None:
            from ipm.degrade import DEGRADATIONS

            if m["mask"] not in DEGRADATIONS or m["mask"] == "none":
                raise ValueError(
                    f"config: methods entry {m['name']}: unknown mask degradation {m['mask']!r} "
                    f"(known: {', '.join(d for d in DEGRADATIONS if d != 'none')})"
                )
        for case in m.get("cases", []):
            load_case(case)  # an unknown name is refused even where cases leaves it out
        if isinstance(m.get("seeds"), dict):
            for case in m["seeds"]:
                if case not in m.get("cases", config["cases"]):
                    raise ValueError(f"config: methods entry {row_id(m)}: seeds for {case}, a case it does not run on")
        for case in method_cases(m):
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


def reconstruct_priority(wildcards):
    """The longest methods first (the GA, instant-NGP-style, then ours), and every reconstruction
    before the evaluations, appearance scores and previews (priority 0), which fill the run's end:
    a long job started last ends the run alone."""
    return METHODS[method_of(wildcards)["name"]].length + 1


def method_views(wildcards):
    return method_of(wildcards)["views"]


def case_generator(wildcards):
    """The generator that reconstructs a case (its 'generator' field)."""
    from ipm.cases import load_case

    return load_case(wildcards.case)["generator"]


def row_info(wildcards):
    """Label and kind of a table row: ours ("method", takes a generator), a baseline, a reference line."""
    if wildcards.row.startswith("line_"):
        name = wildcards.row[len("line_") :]
        return {"label": REFERENCE_LINES[name].label, "kind": "reference"}
    m = method_of(wildcards)
    kind = "method" if METHODS[m["name"]].uses_generator else "baseline"
    tag = f" [{m['tag']}]" if m.get("tag") else ""
    mask = f" [mask: {m['mask']}]" if m.get("mask") else ""
    return {"label": row_label(m["name"], m["views"]) + tag + mask, "kind": kind, "mask": m.get("mask") or ""}


def views_dir(name, views, case, mask=None):
    """Folder of the rendered views that method ``name`` reads for ``views`` views; with ``mask``
    (a degradation of ``ipm.degrade``), their copy with every mask degraded by it."""
    from ipm.degrade import slug

    return f"results/synth/{case}/{METHODS[name].layout}{views}" + (f"_mask{slug(mask)}" if mask else "")


def method_views_dir(wildcards):
    """Folder of the views (transforms.json, rgb/, masks/, semantic/) a row reads on a case."""
    m = method_of(wildcards)
    return views_dir(m["name"], m["views"], wildcards.case, m.get("mask"))


def recovery_views(wildcards):
    """The input views whose semantic images decide which counts parameter recovery scores (the
    row's own; none for baselines and reference lines, which have no counts or no input)."""
    if wildcards.row.startswith("line_") or not METHODS[method_of(wildcards)["name"]].uses_generator:
        return []
    return method_views_dir(wildcards)


def method_inputs(wildcards):
    """Inputs of a reconstruction: its views, and the method's preparation file for the case's
    generator and the run's seed if it has a preparation stage (the GA's gene statistics, made once
    per generator and seed, so the spread over seeds includes theirs; with ``prepare_seed`` set, one
    file made with that seed serves every seed). For a method that compiles its programs per case
    (``Method.compiles``), a seed other than the case's first also waits for the first seed's run,
    then reads them from JAX's cache; ``ancient``: a rerun of the first seed alone reruns no other."""
    m = method_of(wildcards)
    out = {"views": method_views_dir(wildcards)}
    first = method_seeds(m, wildcards.case)[0]
    if METHODS[m["name"]].compiles and int(wildcards.seed) != first:
        out["first_seed"] = ancient(f"results/reconstruct/{wildcards.row}/{wildcards.case}/s{first}")
    stage = preparation(m)
    if stage is not None:
        seed = wildcards.seed if config["prepare_seed"] is None else config["prepare_seed"]
        out["prepared"] = prepared_file(stage, case_generator(wildcards), seed)
    return out


def prepared_file(stage, generator, seed):
    """The preparation file of ``stage`` for ``generator``: with ``prepared: shipped`` the one the
    package ships (the default profile's, seed 0; ``python -m ipm.ship``) where there is one, a
    source file that no storage provider moves (relative to the working directory where it lies
    inside); else the ``prepare`` rule's for ``seed``."""
    from pathlib import Path

    if config["prepared"] == "shipped":
        path = METHODS[stage].shipped_file(generator)
        if path is not None:
            path, here = path.resolve(), Path.cwd().resolve()
            return local(str(path.relative_to(here) if path.is_relative_to(here) else path))
    return f"results/prepare/{stage}/{generator}/s{seed}.json"


def preparation(m):
    """The preparation stage a methods entry reads, by the name of the method that makes it: its
    own method's; for the diff path started from the learned regressor's proposals (the profile's
    ``start``, unless the entry's settings say ``start: presets``) the regressor's; for the
    camera-withheld rows started from the proposed camera (``camera_start: learned``) its
    camera-hidden variant's; None if it needs none."""
    import json

    return _preparation(m["name"], json.dumps(m.get("settings", {}), sort_keys=True))


@functools.lru_cache(maxsize=None)
def _preparation(name, settings):
    """:func:`preparation` of a method ``name`` with its settings as JSON (once per entry)."""
    import json

    from ipm.profiles import get_profile
    from ipm.search.moves.camera import CameraSettings

    if METHODS[name].prepare is not None:
        return name
    prof = get_profile(config["profile"], **json.loads(settings))
    if name == "diff" and prof.loop.start == "learned":
        return "learned"
    if (
        METHODS[name].withholds_camera
        and prof.of(CameraSettings).camera_start == "learned"
        and not prof.of(CameraSettings).fov_grid
    ):
        return "learned_photo"
    return None


RECONSTRUCT_MINUTES = {"smoke": 20, "default": 60, "paper": 24 * 60}
"""Runtime limit of one reconstruction per profile, for cluster executors (the default profile's
slowest job, a GA tree, took about 4 minutes on a 2-core machine; the paper's budgets take hours)."""


GPU = {"gpu": 1} if config["device"] == "cuda" else {}
"""The reconstructions' GPU request: one each with device cuda (bounded by --resources gpu=N
locally, a GPU per job on a cluster), none on the CPU."""


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


def line_applies(name, case):
    """Whether reference line ``name`` applies to ``case`` (the reseeded truth: stochastic in-family cases)."""
    from ipm.cases import load_case

    return REFERENCE_LINES[name].applies(load_case(case))


def all_runs():
    """Every (row id, case, seed) of the table: method rows on their cases and seeds, reference
    lines (no random choices) on every case they apply to, with the case's first seed.
    """
    out = [
        (row_id(m), case, seed) for m in config["methods"] for case in method_cases(m) for seed in method_seeds(m, case)
    ]
    return out + [
        (f"line_{name}", case, case_seeds(case)[0])
        for name in config["reference_lines"]
        for case in config["cases"]
        if line_applies(name, case)
    ]


def run_files(pattern, methods_only=False):
    """``pattern`` (with {row}, {case}, {seed}) for every run, or every run of a method row."""
    return [
        pattern.format(row=r, case=c, seed=s) for r, c, s in all_runs() if not (methods_only and r.startswith("line_"))
    ]


def all_metrics():
    """Metrics files of every run."""
    return run_files("results/evaluate/{row}/{case}/s{seed}/metrics.json")


def all_parts_previews():
    """Part previews of the rows that fit a generator (baselines have no parts)."""
    return [
        f"results/evaluate/{row_id(m)}/{case}/s{seed}/parts.png"
        for m in config["methods"]
        if METHODS[m["name"]].uses_generator
        for case in method_cases(m)
        for seed in method_seeds(m, case)
    ]


def texture_views():
    """Colour views a textured run is scored on (config ``texture.views``; 0: none)."""
    return int(config.get("texture", {}).get("views", 0))


def texture_views_dir(wildcards):
    """The case's colour views in the held layout (the input view, then views no row is given)
    that the appearance of its runs is scored on."""
    return f"results/synth/{wildcards.case}/held{texture_views()}"


def method_appearance(wildcards):
    """The ``module:function`` that renders a row's result for its appearance scores."""
    return METHODS[method_of(wildcards)["name"]].appearance


def all_texture_scores():
    """Appearance scores of every run of an untagged row with an appearance (ours' textures,
    instant-NGP-style's field) on the true masks."""
    n = texture_views()
    return [
        f"results/evaluate/{row_id(m)}/{case}/s{seed}/texture.json"
        for m in config["methods"]
        if n and METHODS[m["name"]].appearance and not m.get("mask") and not m.get("tag")
        for case in method_cases(m)
        for seed in method_seeds(m, case)
    ]


def texture_table_files():
    """The appearance table's files where any run is scored, else none."""
    return ["results/table_texture.csv", "results/table_texture.md"] if all_texture_scores() else []


def report_inputs():
    """Everything the report reads: per run its metrics, table line, pictures and result folder
    (trace, parameters, GLB), the reconstructions' benchmark files, per case the input views and
    the reference's pictures."""
    return {
        "metrics": all_metrics(),
        "rows": run_files("results/evaluate/{row}/{case}/s{seed}/row.json"),
        "previews": run_files("results/evaluate/{row}/{case}/s{seed}/preview.png"),
        "galleries": run_files("results/evaluate/{row}/{case}/s{seed}/gallery.png"),
        "parts": all_parts_previews(),
        "runs": run_files("results/reconstruct/{row}/{case}/s{seed}"),
        "benchmarks": run_files("logs/benchmark/reconstruct/{row}/{case}/s{seed}.tsv", methods_only=True),
        "views": sorted(set(input_view_dirs().values())),
        "references": [
            f"results/synth/{case}/{name}" for case in config["cases"] for name in ("gallery.png", "reference.ply")
        ],
    }


def table_labels():
    """Labels of every row the config asks for, in the table's order (the report check looks for each)."""
    from types import SimpleNamespace

    return list(dict.fromkeys(row_info(SimpleNamespace(row=r))["label"] for r, _, _ in all_runs()))


def get_final_output():
    return [
        "results/table.csv",
        "results/table_iou.csv",
        *texture_table_files(),
        "results/report/index.html",
        "results/report/screenshots",
    ]
