"""The HTML report: Table 1 beside the paper's, every metric, per-case galleries and 3D views,
convergence plots, timing and memory, provenance.

One self-contained file (images as base64, CSS, JS and the 3D models inline), so the page can be
mailed or archived as it is. The data are gathered here into plain dicts and lists; the layout is
the Jinja2 template ``templates/report.html.j2``.
"""
from __future__ import annotations

import base64
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ipm.io.atomic import atomic_path
from reports.plots import _aggregate_bars, _fig, _png, _trace_plot
from reports.provenance import _provenance

HERE = Path(__file__).parent
PAPER_TABLE = HERE / "paper_table1.json"
"""The paper's Table 1 (numbers copied from its LaTeX source, with its caption)."""
MODEL_VIEWER = HERE / "js" / "node_modules" / "@google" / "model-viewer" / "dist" / "model-viewer.min.js"
"""The <model-viewer> web component (``npm ci --prefix reports/js``), inlined once into the page."""
MAX_MODEL_BYTES = 3_000_000
"""Larger GLBs get no interactive 3D view (a note says so), to keep the page a sensible size."""


@dataclass(frozen=True)
class MetricTable:
    """One table of the report: a metric of table.csv laid out as Table 1."""

    metric: str
    """Column of table.csv and table_summary.csv."""
    title: str
    """Heading."""
    higher_is_better: bool
    """Direction in which a value wins the column's "best" mark."""
    note: str
    """What the number is, in a sentence."""
    scale: float = 1.0
    """Factor the values are shown multiplied by (three decimals must tell the methods apart)."""
    caveat: str = ""
    """A boolean column of table.csv: a cell over a run where it is False gets a dagger and says so."""
    caveat_words: str = ""
    """What a False in ``caveat`` means for the number."""


TABLE1 = MetricTable("iou_mean", "64-view silhouette IoU", True,
                     "the paper's metric: silhouettes from 64 Fibonacci-sphere views around the reference, "
                     "IoU per view, mean over views")
SIBLINGS = (
    MetricTable("shape_iou", "Shape IoU after the best similarity alignment", True,
                "the same 64-view IoU after turning, moving and scaling the reconstruction onto the reference: "
                "what is left is the shape's error, the rest of the gap to the world-frame IoU is placement"),
    MetricTable("viou", "Volumetric IoU", True,
                "IoU of the occupancies on a voxel grid over the union of both bounding boxes; † a reconstruction "
                "that is not watertight has no well-defined inside, its number is unreliable",
                caveat="recon_watertight", caveat_words="not watertight, unreliable"),
    MetricTable("chamfer_l1", "Chamfer-L1 × 100", False,
                "mean nearest-neighbour distance between surface samples, both ways averaged, / r "
                "(r: half the reference's bounding-box diagonal), times 100", 100.0),
    MetricTable("chamfer_l2", "Chamfer-L2 × 1000", False,
                "mean squared nearest-neighbour distance between surface samples, both ways summed, / r^2, "
                "times 1000", 1000.0),
    MetricTable("param_err", "Parameter error", False,
                "mean unit-cube error of the generator's continuous parameters against the truth (in-family cases)"),
    MetricTable("discrete_match", "Discrete parameters recovered", True,
                "share of the generator's discrete parameters recovered exactly (in-family cases)"),
    MetricTable("counts_exact", "Counts exact", True,
                "share of runs with every count the input view's window mask shows exact (in-family cases)"),
    MetricTable("camera_pitch_err_deg", "Camera pitch error, camera withheld (degrees)", False,
                "absolute error of the estimated camera's pitch (rows that fit without the camera: photo, "
                "photo_fov); a pitch error moves the object along the ground and scales it, which the world IoU "
                "counts and the shape IoU does not"),
    MetricTable("camera_fov_err_pct", "Field-of-view error, camera withheld (%)", False,
                "absolute relative error of the estimated horizontal field of view, in per cent (rows that fit "
                "without the camera: photo; photo_fov is given it, so 0)"),
)
"""The tables after Table 1, in page order."""


# ---------------------------------------------------------------- 3D views


def _model(folder: Path, label: str) -> dict:
    """The run's mesh for <model-viewer>: its mesh.glb, else its mesh.ply as GLB (flat grey),
    gzipped and base64-encoded (``gz``; the page unpacks it when its 3D view is opened); or no
    ``gz`` and why not (too large, empty, absent)."""
    import gzip

    import trimesh

    if (folder / "mesh.glb").is_file():
        data = (folder / "mesh.glb").read_bytes()
    elif (folder / "mesh.ply").is_file():
        mesh = trimesh.load(folder / "mesh.ply", force="mesh", process=False)
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            return {"gz": None, "note": "no 3D view: the mesh is empty"}
        material = trimesh.visual.material.PBRMaterial(baseColorFactor=[0.55, 0.55, 0.58, 1.0], metallicFactor=0.0,
                                                       roughnessFactor=0.8)
        mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False,
                               visual=trimesh.visual.TextureVisuals(material=material))
        data = mesh.export(file_type="glb")
    else:
        return {"gz": None, "note": "no 3D view: the run wrote no mesh"}
    mb = len(data) / 1e6
    if len(data) > MAX_MODEL_BYTES:
        return {"gz": None, "note": f"no 3D view: the model is {mb:.1f} MB (the page embeds models up to "
                                    f"{MAX_MODEL_BYTES / 1e6:.0f} MB)"}
    return {"gz": base64.b64encode(gzip.compress(data, 6, mtime=0)).decode(), "note": f"{mb:.2f} MB", "alt": label}


# ---------------------------------------------------------------- tables


def _text(value, fmt: str = "{:.3f}") -> str:
    """A cell's text: numbers by ``fmt``, "-" where there is no value."""
    if isinstance(value, (bool, np.bool_)):
        return str(value)
    if isinstance(value, (int, float, np.integer, np.floating)):
        return fmt.format(value) if np.isfinite(value) else "-"
    return "-" if value is None or (isinstance(value, str) and not value) else str(value)


def _frame(frame: pd.DataFrame, fmt: str = "{:.3f}") -> dict:
    """A table for the template: header and rows of text, numbers by ``fmt`` (whole numbers, such as
    seeds and counts, without decimals), "-" where there is no value."""
    numeric = [c for c in frame.columns if pd.api.types.is_numeric_dtype(frame[c])
               and not pd.api.types.is_bool_dtype(frame[c])]
    whole = {c for c in numeric if (frame[c].dropna() % 1 == 0).all()}
    return {"head": [str(c) for c in frame.columns],
            "rows": [[_text(v, "{:.0f}" if c in whole else fmt) for c, v in zip(frame.columns, row)]
                     for row in frame.itertuples(index=False)]}


def _failed(note) -> bool:
    return isinstance(note, str) and note.startswith("failed")


def _runs_where(df: pd.DataFrame, label: str, cases: list[str], which: pd.Series, words: str | None = None) -> str:
    """``label``'s runs on ``cases`` where ``which`` holds, one per run with its note (or ``words``),
    for a cell's ``title``."""
    runs = df.loc[(df["label"] == label) & df["case"].isin(cases) & which, ["case", "seed", "note"]]
    return "; ".join(f"{case} seed {int(seed)}: {words or note}" for case, seed, note in runs.itertuples(False, None))


FAMILIES = {"in": "made by the class's generator", "out": "built by independent code", "all": "all of them"}
"""The aggregate columns' families (``<class>/<split>/<family>``), in words."""


def _members(part: pd.DataFrame, column: str) -> list[str]:
    """The cases a column of a block stands for: itself, or an aggregate's cases of its family."""
    if "/" not in column:
        return [column]
    family = column.rsplit("/", 1)[-1]
    cases = part[~part["case"].str.contains("/")].drop_duplicates("case")
    return list(cases.loc[(family == "all") | (cases["family"] == family), "case"])


def _metric_cell(line, metric: str, text: str, why: str, caveat: str) -> dict:
    """One cell: ``text`` from ``table_blocks`` split into the value (named where it is a row's
    headline other than the table's metric, "shape 0.910") and the rest, the value of ``metric``
    for sorting and the best mark (``v``), classes (failed, n/a, partly failed, caveat) and as
    title the failure reasons ``why`` and the runs the ``caveat`` is about."""
    value = np.nan if line is None else float(getattr(line, metric))
    main, rest = re.fullmatch(r"((?:[a-z]+ )?\S*) ?(.*)", text).groups()
    cell = {"v": f"{value:.6g}" if np.isfinite(value) else "", "main": main, "rest": rest,
            "title": "; ".join(t for t in (why, caveat) if t), "cls": ["caveat"] if caveat else []}
    if line is None:
        cell.update(main="", title="not run on every case of this column")
    elif not np.isfinite(value):
        cell.update(main="-" if why else "n/a", rest="", title=why or "no value (not applicable)",
                    cls=["failed" if why else "na"])
    elif why:
        cell["cls"].append("partly-failed")
    return cell


def _shows(cell: dict) -> bool:
    return bool(cell["v"]) or "failed" in cell["cls"]


def _mark_best(rows: list[dict], higher_is_better: bool) -> None:
    """Add ``best`` to the cells that hold their column's best value (at the three decimals shown);
    reference lines are context and never win."""
    for i in range(len(rows[0]["cells"]) if rows else 0):
        contenders = [r["cells"][i] for r in rows if r["kind"] != "reference" and r["cells"][i]["v"]]
        if not contenders:
            continue
        values = [round(float(c["v"]), 3) for c in contenders]
        best = max(values) if higher_is_better else min(values)
        for c, v in zip(contenders, values):
            if v == best:
                c["cls"].append("best")


def metric_blocks(summary: pd.DataFrame, df: pd.DataFrame, spec: MetricTable, split: str) -> list[dict]:
    """Per class, ``spec.metric`` on ``split`` as rows (method x views) x columns (cases, then the
    class aggregates), laid out and worded by ``ipm.table.table_blocks``; each cell with its value
    (for sorting), the best mark and, for failures, the reason. Rows and columns without any value
    or failure (e.g. parameter errors of a baseline) are left out."""
    from ipm.table import CLASS_NAMES, headline, table_blocks

    blocks = []
    for gen in summary["generator"].dropna().unique():
        part = summary[(summary["split"] == split) & (summary["generator"] == gen)]
        if part.empty:
            continue
        scaled = [c for c in (spec.metric, f"{spec.metric}_std", f"{spec.metric}_worst") if c in part]
        part = part.assign(**{c: part[c] * spec.scale for c in scaled})
        [(_, header, text_rows, note)] = table_blocks(part, spec.metric)
        columns = header[1:]
        lines = {(r.label, r.case): r for r in part.itertuples()}
        leads = {r.label: headline(r.row, spec.metric) for r in part.itertuples()}
        members = {c: _members(part, c) for c in columns}
        failed = df["note"].map(_failed)
        doubtful = (df[spec.caveat] == False) if spec.caveat in df else pd.Series(False, index=df.index)  # noqa: E712
        rows = [{"label": label, "kind": part.loc[part["label"] == label, "kind"].iloc[0],
                 "cells": [_metric_cell(lines.get((label, c)), leads[label], text,
                                        _runs_where(df, label, members[c], failed),
                                        _runs_where(df, label, members[c], doubtful, f"† {spec.caveat_words}"))
                           for c, text in zip(columns, texts)]}
                for label, *texts in text_rows]
        keep = [i for i in range(len(columns)) if any(_shows(r["cells"][i]) for r in rows)]
        rows = [{**r, "cells": [r["cells"][i] for i in keep]} for r in rows if any(_shows(r["cells"][i]) for i in keep)]
        if not rows:
            continue
        _mark_best(rows, spec.higher_is_better)
        name = CLASS_NAMES.get(gen, gen)
        blocks.append({"title": f"{name}, {split} split", "metric": spec.metric, "split": split, "rows": rows,
                       "note": note,
                       "columns": [{"name": columns[i], "aggregate": "/" in columns[i],
                                    "title": f"mean over the {split} {name} {FAMILIES[columns[i].rsplit('/', 1)[-1]]}"
                                    if "/" in columns[i] else ""} for i in keep]})
    return blocks


def _recovery(summary: pd.DataFrame) -> dict | None:
    rec = summary[summary["param_err"].notna() & ~summary["case"].str.contains("/", na=False)]
    cols = ["label", "split", "case", "n_seeds", "param_err", "param_err_max", "discrete_match", "counts_exact",
            "yaw_err_deg", "trans_err_rel", "size_err_pct"]
    return None if rec.empty else _frame(rec[cols])


def _masks(df: pd.DataFrame) -> dict | None:
    """The mask rows against their true-mask twins (``reports.masks``), None without mask rows."""
    from reports.masks import mask_errors

    out = mask_errors(df)
    return None if out is None else {**out, "table": _frame(out["table"])}


def _textures(path: str | None) -> dict | None:
    """The appearance table (``ipm.table.texture_table``), None where no run was scored."""
    if not path:
        return None
    df = pd.read_csv(path)
    return None if df.empty else _frame(df, "{:.3f}")


def _benchmarks(paths: list[str]) -> pd.DataFrame:
    """Snakemake's benchmark TSVs of the reconstructions, one line each with row, case and seed
    from the path (``.../{row}/{case}/s{seed}.tsv``)."""
    lines = []
    for p in map(Path, paths):
        if not p.is_file():
            continue
        b = pd.read_csv(p, sep="\t").apply(pd.to_numeric, errors="coerce")
        for r in b.itertuples():
            lines.append({"row": p.parent.parent.name, "case": p.parent.name, "seed": int(p.stem.lstrip("s")),
                          "s": r.s, "max_rss": r.max_rss, "cpu_time": r.cpu_time})
    return pd.DataFrame(lines, columns=["row", "case", "seed", "s", "max_rss", "cpu_time"])


def _timing(df: pd.DataFrame, benchmarks: list[str]) -> dict:
    """Per method: runs, the reconstruction's own clock (table.csv), the job's wall time, CPU time
    and peak resident memory (Snakemake's benchmark files)."""
    labels = dict(zip(df["row"], df["label"]))
    own = df.groupby("label", sort=False)["seconds"].agg(["count", "mean", "max"])
    bench = _benchmarks(benchmarks)
    bench["label"] = bench["row"].map(lambda r: labels.get(r, r))
    jobs = bench.groupby("label", sort=False).agg(jobs=("s", "size"), s_mean=("s", "mean"), s_max=("s", "max"),
                                                  cpu_mean=("cpu_time", "mean"), rss_mean=("max_rss", "mean"),
                                                  rss_peak=("max_rss", "max"))
    table = own.join(jobs, how="outer").reindex(list(dict.fromkeys([*own.index, *jobs.index])))
    table = table.reset_index().rename(columns={
        "index": "method", "label": "method", "count": "runs", "mean": "reconstruction s (mean)",
        "max": "reconstruction s (max)", "jobs": "benchmarked jobs", "s_mean": "job s (mean)", "s_max": "job s (max)",
        "cpu_mean": "CPU s (mean)", "rss_mean": "RSS MB (mean)", "rss_peak": "peak RSS MB"})
    return {"table": _frame(table, "{:.1f}"), "n_files": len(bench)}


# ---------------------------------------------------------------- per case


def _number(line: pd.Series, key: str) -> float:
    """``line[key]`` as a float, NaN where absent or not a number."""
    try:
        return float(line[key])
    except (KeyError, TypeError, ValueError):
        return np.nan


def _shown_run(g: pd.DataFrame) -> pd.Series:
    """The run whose pictures are shown: the first seed that did not fail (else the first)."""
    ok = g[~g["note"].map(_failed)]
    return (ok if len(ok) else g).iloc[0]


def _run_card(g: pd.DataFrame, results: Path, models: bool) -> dict:
    """One method on one case: its seeds' headline IoUs, the shown seed's metrics, pictures, trace and 3D view."""
    from ipm.table import scored_by

    first = _shown_run(g)
    row, case, seed = first["row"], first["case"], int(first["seed"])
    lead = scored_by(row)
    folder = results / "evaluate" / row / case / f"s{seed}"
    recon = results / "reconstruct" / row / case / f"s{seed}"
    card = {"label": first["label"], "kind": first["kind"], "seed": seed, "failed": _failed(first["note"]),
            "note": first["note"] if isinstance(first["note"], str) else "",
            "per_seed": "shape IoU" if lead == "shape_iou" else "IoU",
            "seeds": [{"seed": int(r.seed), "iou": _text(getattr(r, lead)), "failed": _failed(r.note),
                       "note": r.note if isinstance(r.note, str) else ""} for r in g.itertuples()],
            "metrics": [(name, _text(_number(first, key), fmt)) for name, key, fmt in (
                ("IoU", "iou_mean", "{:.3f}"), ("shape IoU", "shape_iou", "{:.3f}"), ("vIoU", "viou", "{:.3f}"),
                ("Chamfer-L1", "chamfer_l1", "{:.4f}"), ("Chamfer-L2", "chamfer_l2", "{:.4f}"),
                ("triangles", "n_triangles", "{:,.0f}"), ("malformed", "malformed_share", "{:.1%}"),
                ("seconds", "seconds", "{:.1f}"), ("CPU seconds", "cpu_seconds", "{:.1f}"))],
            "machine": first["machine"] if isinstance(first.get("machine"), str) else "not recorded",
            "gallery": _png(folder / "gallery.png"), "preview": _png(folder / "preview.png"),
            "parts": _png(folder / "parts.png") or _png(recon / "parts.png"), "trace": None, "pose": "",
            "model": _model(recon, f"{first['label']} on {case}") if models else None}
    info = json.loads((recon / "params.json").read_text()) if (recon / "params.json").is_file() else None
    if (recon / "trace.csv").is_file():
        trace = pd.read_csv(recon / "trace.csv")
        if len(trace):
            card["trace"] = _fig(_trace_plot(trace, (info or {}).get("loss", "silhouette")))
    if info is not None and "pose" in info:
        pose = {k: (round(v, 3) if isinstance(v, float) else [round(x, 3) for x in v]) for k, v in info["pose"].items()}
        extra = [f"{k} {info['params'][k]}" for k in ("has_handle",) if k in info.get("params", {})]
        if "branch_graph_vertices" in info:
            extra.append(f"branch graph {info['branch_graph_vertices']} vertices")
        card["pose"] = "; ".join([f"pose {json.dumps(pose)}", *extra, f"{info.get('evaluations')} evaluations",
                                  f"final loss {_text(info.get('final_loss'), '{:.5f}')}"])
    return card


def _reference_triangles(path: Path) -> str:
    """The reference's triangle count, "" when its mesh is not at hand (not an input of the job)."""
    import trimesh

    return f"{len(trimesh.load(path, force='mesh', process=False).faces):,}" if path.is_file() else ""


def _cases(df: pd.DataFrame, config: dict, input_dirs: dict, results: Path, models: bool) -> list[dict]:
    out = []
    for case in config.get("cases") or list(dict.fromkeys(df["case"])):
        runs = df[df["case"] == case]
        if runs.empty:
            continue
        first = runs.iloc[0]
        synth = Path(input_dirs.get(case, results / "synth" / case))
        out.append({"name": case, "split": first["split"], "generator": first["generator"], "family": first["family"],
                    "rgb": _png(synth / "rgb" / "000.png"), "mask": _png(synth / "masks" / "000.png"),
                    "reference": _png(results / "synth" / case / "gallery.png"),
                    "reference_triangles": _reference_triangles(results / "synth" / case / "reference.ply"),
                    "runs": [_run_card(g, results, models) for _, g in runs.groupby("row", sort=False)]})
    return out


# ---------------------------------------------------------------- the page


def build_report(table_csv: str, wide_csv: str, metrics: list[str], out_html: str, config: dict,
                 input_dirs: dict | None = None, summary_csv: str | None = None,
                 benchmarks: list[str] | None = None, texture_csv: str | None = None) -> None:
    """Write ``out_html``, atomically, from the tables (``table_csv``, ``summary_csv``; the summary
    is made from the long table when not given), the per-run folders beside them (results/evaluate,
    results/reconstruct, results/synth), Snakemake's ``benchmarks`` of the reconstructions
    (``logs/benchmark/reconstruct/{row}/{case}/s{seed}.tsv``) and ``config``; ``input_dirs`` maps a
    case to the folder of its input views; ``texture_csv`` the textured rows' appearance table
    (``ipm.table.texture_table``). ``wide_csv`` and ``metrics`` are the table step's other
    outputs and inputs (the DAG's dependencies; the page reads the long table)."""
    import jinja2

    from ipm.table import summary_table

    df = pd.read_csv(table_csv)
    summary = pd.read_csv(summary_csv) if summary_csv else summary_table(df)
    if any(t.metric not in summary for t in (TABLE1, *SIBLINGS)):  # a summary written by an older version
        summary = summary_table(df)
    results = Path(table_csv).parent
    models = MODEL_VIEWER.is_file()
    bars = _aggregate_bars(summary)
    cases = _cases(df, config, input_dirs or {}, results, models)
    embedded = sum(1 for c in cases for r in c["runs"] if r["model"] and r["model"]["gz"])
    splits = ("test", "dev")
    page = {
        "config": config, "cases_by_split": df.drop_duplicates("case").groupby("split", sort=False)["case"].apply(list),
        "table1": {s: metric_blocks(summary, df, TABLE1, s) for s in splits}, "table1_spec": TABLE1,
        "siblings": [{"spec": t, **{s: metric_blocks(summary, df, t, s) for s in splits}}
                     for t in SIBLINGS if t.metric in summary],
        "paper": json.loads(PAPER_TABLE.read_text()), "bars": _fig(bars) if bars is not None else None,
        "recovery": _recovery(summary), "masks": _masks(df), "textures": _textures(texture_csv), "timing": _timing(df, benchmarks or []), "cases": cases,
        "runs": _frame(df.drop(columns=["row", "kind"]), "{:.4f}"), "provenance": _provenance(df, config),
        "model_viewer": MODEL_VIEWER.read_text().replace("</script", "<\\/script") if models and embedded else None,
        "models_off": None if models else f"3D views off: {MODEL_VIEWER.relative_to(HERE.parent)} is missing "
                                          "(npm ci --prefix reports/js)",
    }
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(HERE / "templates"), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    html = env.get_template("report.html.j2").render(**page)
    with atomic_path(out_html) as tmp:
        tmp.write_text(html)
