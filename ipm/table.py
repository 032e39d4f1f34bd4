"""Table 1: one row per (method, case) with every metric, and the IoU pivot like the paper's.

A metrics file lives at ``results/evaluate/<row>/<case>/metrics.json`` beside ``row.json``
(label, kind, wall time of the reconstruction, a note such as a failure's reason), both written
by the evaluate step. A failed run has no metrics: its cells are empty and show as "-".
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ipm.io.atomic import atomic_path

COLUMNS = ["row", "label", "kind", "case", "iou_mean", "iou_min", "iou_std", "iou_above", "iou_below",
           "viou", "recon_watertight", "chamfer_l2", "chamfer_l1", "n_triangles", "malformed_share", "seconds", "note"]
KINDS = ("baseline", "method", "reference")
"""Row kinds in table order: general-purpose baselines, ours, reference lines (as in the paper)."""


def _row(metrics_path: Path) -> dict:
    m = json.loads(metrics_path.read_text())
    info = json.loads((metrics_path.parent / "row.json").read_text())
    return {"row": metrics_path.parent.parent.name, "case": metrics_path.parent.name, **info,
            **{k: m[k] for k in COLUMNS if k in m}}


def build_table(metrics: list[str], table_csv: str, wide_csv: str) -> pd.DataFrame:
    """Collect metrics into ``table_csv`` (long) and ``wide_csv`` (label x case mean IoU)."""
    df = pd.DataFrame([_row(Path(p)) for p in metrics])
    df = df.reindex(columns=COLUMNS)
    rank = df["kind"].map({k: i for i, k in enumerate(KINDS)}).fillna(len(KINDS))
    df = df.iloc[np.argsort(rank.to_numpy(), kind="stable")]  # kinds in KINDS order, rows as configured
    wide = df.pivot(index="label", columns="case", values="iou_mean")  # failed runs stay as NaN ("-")
    wide = wide.loc[df["label"].drop_duplicates(), df["case"].drop_duplicates()]  # config order
    with atomic_path(table_csv) as tmp:
        df.to_csv(tmp, index=False, float_format="%.4f")
    with atomic_path(wide_csv) as tmp:
        wide.to_csv(tmp, float_format="%.3f")
    return df
