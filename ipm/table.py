"""Table 1: every (method, case, seed) with every metric, its summary over seeds, and class aggregates.

A metrics file lives at ``results/evaluate/<row>/<case>/s<seed>/metrics.json`` beside ``row.json``
(label, kind, the case's split and generator, seed, wall time of the reconstruction, a note such
as a failure's reason), both written by the evaluate step. A failed run has no metrics: its cells
are empty and show as "-".

- ``table.csv``: one line per run (long);
- ``table_summary.csv``: per (row, case) the mean, sample standard deviation and worst over seeds
  of the IoUs, and means of the rest; then per (row, class, split, family) an aggregate line
  (``case`` = ``<class>/<split>/<family>``): the mean over the cases of their seed means (the
  paper's "average IoU"), the standard deviation over seeds of the per-seed mean over the cases,
  and the worst case;
- ``table_iou.csv``: label x case (then aggregates) of the mean 64-view IoU, as the paper lays out;
- ``table1.md``: Markdown tables per class and split (test first) for the README.

A row's headline in Table 1 is its method's ``scored_by`` (``ipm.methods``): the shape IoU where
the camera is withheld, its cells then also give the world IoU and the camera's errors.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ipm.io.atomic import atomic_path
from ipm.metrics.recovery import CAMERA_COLUMNS, RECOVERY_COLUMNS

COLUMNS = ["row", "label", "kind", "mask", "case", "split", "generator", "family", "seed", "iou_mean", "iou_min", "iou_std",
           "iou_above", "iou_below", "shape_iou", "align_yaw_deg", "align_shift", "align_scale", "viou",
           "recon_watertight", "chamfer_l2", "chamfer_l1", "n_triangles", "malformed_share", *RECOVERY_COLUMNS,
           *CAMERA_COLUMNS, "seconds", "cpu_seconds", "machine", "note"]
KINDS = ("baseline", "method", "reference")
"""Row kinds in table order: general-purpose baselines, ours, reference lines (as in the paper)."""
SPREAD = ("iou_mean", "shape_iou", "viou")
"""Metrics summarised by mean, standard deviation and worst (lowest) over seeds."""
MEANS = ("chamfer_l2", "chamfer_l1", "malformed_share", *RECOVERY_COLUMNS, *CAMERA_COLUMNS, "seconds", "cpu_seconds")
"""Metrics summarised by their mean over seeds."""
CLASS_NAMES = {"dishes": "cups", "trees": "trees", "buildings": "buildings"}
"""Table names of the classes, by the generator that reconstructs them."""
WORDS = {"iou_mean": "world", "shape_iou": "shape"}
"""How a cell names an IoU that is not its table's metric."""
CAMERA_WORDS = {"camera_pitch_err_deg": "pitch error {:.1f}°", "camera_fov_err_pct": "FOV error {:.1f}%",
                "mask_iou": "mask IoU {:.3f}"}
"""How a camera-withheld row's cell gives the camera's errors (``CAMERA_COLUMNS``)."""
_ROW_PARTS = re.compile(r"(?P<name>[a-z0-9_]+?)_(?P<views>[0-9]+)v(?:_(?P<tag>(?!mask)[a-z0-9]+))?"
                        r"(?:_mask(?P<mask>[a-z0-9]+))?")
ROW_ID = "(?!line_)" + re.sub(r"\(\?P<\w+>", "(?:", _ROW_PARTS.pattern)
"""Row ids of methods (:func:`row_id`), the workflow's constraint on its ``row`` wildcard."""


def row_id(entry: dict) -> str:
    """The row id of a config's methods entry: ``<name>_<views>v``, then ``_<tag>`` if it has one
    and ``_mask<degradation's slug>`` if it reads degraded masks, e.g. visual_hull_12v, ga_1v_labels,
    diff_1v_maskedgep2px."""
    from ipm.degrade import slug

    return (f"{entry['name']}_{entry['views']}v" + (f"_{entry['tag']}" if entry.get("tag") else "")
            + (f"_mask{slug(entry['mask'])}" if entry.get("mask") else ""))


def _match(row: str) -> re.Match | None:
    """``row`` matched by the row-id grammar with its parts named, None if it is no method's row."""
    return _ROW_PARTS.fullmatch(row) if re.fullmatch(ROW_ID, row) else None


def row_parts(row: str) -> dict | None:
    """A method's row id (:func:`row_id`) taken apart: its ``name``, ``views``, ``tag`` and ``mask``
    (the degradation's slug; None where the row has none); None for a row of no method (a
    reference line's)."""
    m = _match(row)
    return {**m.groupdict(), "views": int(m["views"])} if m else None


def untagged(row: str) -> str | None:
    """The row id of ``row``'s twin without its tag (the same method, views and masks), or None
    where ``row`` is no method's or has no tag."""
    m = _match(row)
    return row[:m.start("tag") - 1] + row[m.end("tag"):] if m and m["tag"] else None


def scored_by(row: str) -> str:
    """The headline metric of row id ``row``: its method's ``scored_by``; the world IoU for rows of
    no catalogued method (reference lines)."""
    from ipm.methods import METHODS

    parts = row_parts(row)
    return METHODS[parts["name"]].scored_by if parts and parts["name"] in METHODS else "iou_mean"


def headline(row: str, metric: str) -> str:
    """What a cell of ``row`` in a table of ``metric`` leads with: the row's headline in Table 1
    (``iou_mean``), ``metric`` itself in every other table."""
    return scored_by(row) if metric == "iou_mean" else metric


def _row(metrics_path: Path) -> dict:
    m = json.loads(metrics_path.read_text())
    info = json.loads((metrics_path.parent / "row.json").read_text())
    return {"row": metrics_path.parent.parent.parent.name, "case": metrics_path.parent.parent.name, **info,
            **{k: m[k] for k in COLUMNS if k in m and k not in info}}


def _family(case: str) -> str:
    """``in`` or ``out`` of its generator's family (``ipm.cases.case_family``)."""
    from ipm.cases import case_family, load_case

    return case_family(load_case(case))


def long_table(metrics: list[str]) -> pd.DataFrame:
    """One line per run, kinds in :data:`KINDS` order, rows and cases as configured."""
    df = pd.DataFrame([_row(Path(p)) for p in metrics])
    df["family"] = df["case"].map({c: _family(c) for c in df["case"].unique()})
    df = df.reindex(columns=COLUMNS)
    rank = df["kind"].map({k: i for i, k in enumerate(KINDS)}).fillna(len(KINDS))
    return df.iloc[np.argsort(rank.to_numpy(), kind="stable")].reset_index(drop=True)


def _spread(values: pd.Series) -> dict:
    v = values.dropna().to_numpy(float)
    return {"mean": float(v.mean()) if v.size else np.nan, "std": float(v.std(ddof=1)) if v.size > 1 else np.nan,
            "worst": float(v.min()) if v.size else np.nan}


def summary_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per (row, case) over seeds, then per (row, class, split, family) over cases (module docstring)."""
    keys = ["row", "label", "kind", "split", "generator", "family", "case"]
    lines = []
    for key, g in df.groupby(keys, sort=False):
        line = dict(zip(keys, key), n_seeds=len(g), n_failed=int(g["iou_mean"].isna().sum()))
        for m in SPREAD:
            s = _spread(g[m])
            line.update({m: s["mean"], f"{m}_std": s["std"], f"{m}_worst": s["worst"]})
        line.update({m: float(g[m].mean()) if g[m].notna().any() else np.nan for m in MEANS})
        lines.append(line)
    per_case = pd.DataFrame(lines)
    groups = {}  # (split, generator, family) -> every case of the table in it
    for (split, gen), g in per_case.groupby(["split", "generator"], sort=False):
        cases = g.drop_duplicates("case")
        if cases["family"].nunique() > 1:  # else in/out would repeat "all"
            for family in ("in", "out"):
                groups[(split, gen, family)] = list(cases.loc[cases["family"] == family, "case"])
        groups[(split, gen, "all")] = list(cases["case"])
    aggregates = []
    for row, g in per_case.groupby("row", sort=False):
        for (split, gen, family), cases in groups.items():
            part = g[g["case"].isin(cases) & (g["split"] == split)]
            if len(part) < len(cases):  # the row skipped some of the group's cases: no average
                continue
            runs = df[(df["row"] == row) & df["case"].isin(cases)]
            agg = {k: part.iloc[0][k] for k in ("row", "label", "kind")}
            agg.update(split=split, generator=gen, family=family, case=f"{CLASS_NAMES.get(gen, gen)}/{split}/{family}",
                       n_cases=len(part), n_seeds=int(part["n_seeds"].max()),
                       n_failed=int((part["n_failed"] == part["n_seeds"]).sum()))
            for m in SPREAD:
                agg[m] = float(part[m].mean()) if part[m].notna().all() else np.nan
                agg[f"{m}_worst"] = float(part[m].min()) if part[m].notna().all() else np.nan
            for m in dict.fromkeys(("iou_mean", scored_by(row))):  # the world IoU's spread, and the headline's
                by_seed = runs.pivot_table(index="seed", columns="case", values=m, aggfunc="first")
                complete = by_seed.dropna()  # seeds every case of the group has
                agg[f"{m}_std"] = (float(complete.mean(axis=1).std(ddof=1))
                                   if len(complete) > 1 and agg["n_failed"] == 0 else np.nan)
            agg.update({m: float(part[m].mean()) if part[m].notna().any() else np.nan for m in MEANS})
            aggregates.append(agg)
    out = pd.concat([per_case, pd.DataFrame(aggregates)], ignore_index=True)
    front = ["row", "label", "kind", "split", "generator", "family", "case", "n_cases", "n_seeds", "n_failed"]
    return out.reindex(columns=front + [c for c in out.columns if c not in front])


def _cell(mean: float, std: float, worst: float, n_failed: int = 0, n: int = 1) -> str:
    if not np.isfinite(mean):
        return "-"
    text = f"{mean:.3f}"
    if np.isfinite(std):
        text += f" ± {std:.3f}"
    if np.isfinite(worst) and n > 1:
        text += f" (worst {worst:.3f})"
    if n_failed:
        text += f" ({n_failed} failed)"
    return text


SHAPE_NOTE = ("{rows}: scored by the shape IoU (the same 64-view IoU after the best similarity alignment), the world "
              "IoU and the camera's errors beside it, because their camera is withheld and one uncalibrated photo "
              "fixes neither the object's size against its distance nor, for a cup, the lens.")
"""The line under a Table 1 block with camera-withheld rows."""


def _line_cell(r, metric: str, n: int) -> str:
    """Summary line ``r``'s cell in a table of ``metric``: :func:`_cell` of its headline; where that
    is not ``metric`` (a camera-withheld row in Table 1), named, then ``metric`` and the camera's errors."""
    lead = headline(r.row, metric)
    text = _cell(getattr(r, lead), getattr(r, f"{lead}_std", np.nan), getattr(r, f"{lead}_worst", np.nan),
                 int(r.n_failed), n)
    if lead == metric or text == "-":
        return text
    beside = [(f"{WORDS[metric]} {{:.3f}}", getattr(r, metric, np.nan)),
              *((words, getattr(r, c, np.nan)) for c, words in CAMERA_WORDS.items())]
    return " · ".join([f"{WORDS[lead]} {text}", *(words.format(v) for words, v in beside if np.isfinite(v))])


def table_blocks(summary: pd.DataFrame, metric: str = "iou_mean") -> list[tuple[str, list[str], list[list[str]], str]]:
    """Tables of ``metric`` as (title, header, rows of cells, a note or ""), one per class and split,
    test split first: rows x cases and aggregates; cells are mean ± standard deviation over seeds
    (worst seed); aggregates are means over the cases, ± the standard deviation over seeds of that
    mean (worst case). Camera-withheld rows lead with their headline (:func:`headline`), the note says so."""
    out = []
    for split in ("test", "dev"):
        for gen in summary["generator"].dropna().unique():
            part = summary[(summary["split"] == split) & (summary["generator"] == gen)]
            if part.empty:
                continue
            cols = list(dict.fromkeys(part["case"]))
            rows, by_shape = [], []
            for label, g in part.groupby("label", sort=False):
                by_case = {r.case: r for r in g.itertuples()}
                if headline(g["row"].iloc[0], metric) != metric:
                    by_shape.append(label)
                cells = [label]
                for c in cols:
                    r = by_case.get(c)
                    n = 0 if r is None else (r.n_cases if "/" in r.case else r.n_seeds)
                    cells.append("" if r is None else _line_cell(r, metric, int(n)))
                rows.append(cells)
            note = SHAPE_NOTE.format(rows=", ".join(by_shape)) if by_shape else ""
            out.append((f"{CLASS_NAMES.get(gen, gen)}, {split} split ({metric})", ["row", *cols], rows, note))
    return out


def markdown(summary: pd.DataFrame, metric: str = "iou_mean") -> str:
    """:func:`table_blocks` as Markdown, each block's note under it."""
    lines = []
    for title, header, rows, note in table_blocks(summary, metric):
        lines += [f"**{title}**", "", "| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
        lines += ["| " + " | ".join(r) + " |" for r in rows] + [""] + ([note, ""] if note else [])
    return "\n".join(lines)


def build_table(metrics: list[str], table_csv: str, wide_csv: str, summary_csv: str | None = None,
                markdown_path: str | None = None, cases: list[str] | None = None) -> pd.DataFrame:
    """Collect metrics into ``table_csv`` (long), ``summary_csv`` (over seeds and cases),
    ``wide_csv`` (label x case mean IoU, aggregates last; the case columns in the order of
    ``cases``, the configured one, where given) and ``markdown_path``."""
    df = long_table(metrics)
    summary = summary_table(df)
    wide = summary.pivot_table(index="label", columns="case", values="iou_mean", aggfunc="first", dropna=False)
    present, order = list(df["case"].drop_duplicates()), list(cases or [])
    cases = [c for c in order if c in present] + [c for c in present if c not in order]
    aggs = [c for c in summary["case"].drop_duplicates() if c not in cases]
    wide = wide.reindex(index=list(df["label"].drop_duplicates()), columns=cases + aggs)  # failed runs: NaN ("-")
    with atomic_path(table_csv) as tmp:
        df.to_csv(tmp, index=False, float_format="%.6g")
    with atomic_path(wide_csv) as tmp:
        wide.to_csv(tmp, float_format="%.3f")
    if summary_csv:
        with atomic_path(summary_csv) as tmp:
            summary.to_csv(tmp, index=False, float_format="%.6g")
    if markdown_path:
        with atomic_path(markdown_path) as tmp:
            tmp.write_text(markdown(summary) + "\n" + markdown(summary, "shape_iou") + "\n")
    return df


def texture_table(scores: list[str]) -> pd.DataFrame:
    """The textured rows' appearance (``texture.json`` of each run, ``ipm.metrics.texture``): per
    row, case and side, PSNR and SSIM, mean and standard deviation over seeds."""
    lines = []
    for path in scores:
        s = json.loads(Path(path).read_text())
        for side, v in s["sides"].items():
            lines.append({"label": s["label"], "split": s["split"], "case": s["case"], "inputs": s["inputs"],
                          "seed": s["seed"], "side": side, "psnr": v["psnr"], "ssim": v["ssim"]})
    cols = ["label", "split", "case", "inputs", "side", "n_seeds", "psnr", "psnr_std", "ssim", "ssim_std"]
    if not lines:
        return pd.DataFrame(columns=cols)
    df = pd.DataFrame(lines)
    g = df.groupby(["label", "split", "case", "inputs", "side"], sort=False)
    out = g[["psnr", "ssim"]].mean().join(g[["psnr", "ssim"]].std(ddof=1).add_suffix("_std"))
    return out.join(g.size().rename("n_seeds")).reset_index().reindex(columns=cols)


def texture_markdown(table: pd.DataFrame) -> str:
    """The appearance table as markdown: a line per row and case, PSNR (dB) / SSIM per side."""
    sides = ("input", "seen", "unseen")
    head = ["| split | case | row | " + " | ".join(f"{s} PSNR / SSIM" for s in sides) + " |",
            "|" + "---|" * (3 + len(sides))]
    lines = []
    for (split, case, label), g in table.groupby(["split", "case", "label"], sort=False):
        cells = []
        for side in sides:
            r = g[g["side"] == side]
            cells.append("-" if r.empty else f"{r['psnr'].iloc[0]:.1f} / {r['ssim'].iloc[0]:.3f}")
        lines.append(f"| {split} | {case} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(head + lines) + "\n"
