"""The report's mask errors: rows that read degraded masks (a methods entry's ``mask``,
``ipm.degrade``) against the same method's row on the true masks, paired by case and seed."""
from __future__ import annotations

import pandas as pd

METRICS = {"shape_iou": "shape IoU", "iou_mean": "world IoU"}
"""What a degraded mask costs, each as the report names it."""
STYLES = {"shape_iou": "o-", "iou_mean": "s--"}
"""Each metric's line in the plot: shape IoU solid, world IoU dashed."""


def mask_pairs(df: pd.DataFrame) -> pd.DataFrame:
    """One line per run of a mask row with its true-mask twin's run (the label without the mask,
    same case and seed): the degradation, the class, both runs' shape and world IoU and the loss of
    each (positive: the degraded mask's fit is worse). Empty where the run has no mask rows."""
    cols = ["label", "mask", "generator", "split", "case", "seed", *(f"{m}{s}" for m in METRICS
                                                                      for s in ("", "_true", "_loss"))]
    if "mask" not in df:
        return pd.DataFrame(columns=cols)
    masked = df[df["mask"].notna() & (df["mask"].astype(str) != "")]
    lines = []
    for _, run in masked.iterrows():
        base = str(run["label"]).replace(f" [mask: {run['mask']}]", "")
        twin = df[(df["label"] == base) & (df["case"] == run["case"]) & (df["seed"] == run["seed"])]
        if twin.empty:
            continue
        line = {"label": base, "mask": run["mask"], "generator": run["generator"], "split": run["split"],
                "case": run["case"], "seed": run["seed"]}
        for m in METRICS:
            line[m], line[f"{m}_true"] = float(run[m]), float(twin.iloc[0][m])
            line[f"{m}_loss"] = line[f"{m}_true"] - line[m]
        lines.append(line)
    return pd.DataFrame(lines, columns=cols)


def mask_table(pairs: pd.DataFrame) -> pd.DataFrame:
    """Per row, class and degradation: runs, mean loss of shape and world IoU, and the worst
    (largest) loss of shape IoU over cases and seeds."""
    g = pairs.groupby(["label", "generator", "mask"], sort=False)
    out = g.agg(runs=("case", "size"), shape_loss=("shape_iou_loss", "mean"), shape_loss_worst=("shape_iou_loss", "max"),
                world_loss=("iou_mean_loss", "mean")).reset_index()
    return out.rename(columns={"generator": "class", "mask": "degradation", "shape_loss": "shape IoU lost (mean)",
                               "shape_loss_worst": "shape IoU lost (worst)", "world_loss": "world IoU lost (mean)"})


def mask_plot(pairs: pd.DataFrame):
    """Shape and world IoU (mean over cases and seeds) against the mask edge's shift, one panel per
    class and a line per row; None without edge shifts."""
    import matplotlib.pyplot as plt

    from ipm.degrade import edge_shift
    from ipm.table import CLASS_NAMES

    shifted = pairs[pairs["mask"].map(lambda n: edge_shift(str(n)) is not None)]
    if shifted.empty:
        return None
    classes = list(dict.fromkeys(shifted["generator"]))
    fig, axes = plt.subplots(1, len(classes), figsize=(4.6 * len(classes), 3.3), squeeze=False)
    for ax, generator in zip(axes[0], classes):
        part = shifted[shifted["generator"] == generator]
        for label, rows in part.groupby("label", sort=False):
            for metric, name in METRICS.items():
                points = {0.0: float(rows[f"{metric}_true"].mean())}
                for degradation, g in rows.groupby("mask"):
                    points[edge_shift(str(degradation))] = float(g[metric].mean())
                xs = sorted(points)
                ax.plot(xs, [points[x] for x in xs], STYLES[metric], label=f"{label}: {name}")
        ax.set(title=CLASS_NAMES.get(generator, generator), xlabel="mask edge moved (px at 256 px; - inwards)",
               ylabel="64-view IoU, mean over runs")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def mask_errors(df: pd.DataFrame) -> dict | None:
    """The report's section: the plot and the table, None where the run has no mask rows."""
    from reports.plots import _fig

    pairs = mask_pairs(df)
    if pairs.empty:
        return None
    fig = mask_plot(pairs)
    return {"plot": _fig(fig) if fig is not None else None, "table": mask_table(pairs), "n_runs": len(pairs)}
