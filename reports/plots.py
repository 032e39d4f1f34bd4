"""The report's pictures: PNG files and matplotlib figures as data URIs, the convergence plots and
the class aggregates' bars (``reports.build``)."""
from __future__ import annotations

import base64
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402


def _uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode()}"


def _png(path: Path) -> str | None:
    """``path`` as a data URI, None if it is not there."""
    return _uri(path.read_bytes(), "image/png") if path.is_file() else None


def _fig(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return _uri(buf.getvalue(), "image/png")


def _trace_plot(trace: pd.DataFrame, loss: str = "silhouette"):
    """Loss against evaluations and, where the trace has ``seconds``, against wall time: the diff
    path's stages and resolutions, or the GA's tree levels (leaves 0, root highest); the black line
    is the best so far. Where the trace has ``iou`` (the diff path: the input-view IoU of each
    stage's best, at the stage's end), a second row plots it against the same axes."""
    xs = [("eval", "evaluation")] + ([("seconds", "wall time (s)")] if "seconds" in trace else [])
    iou = trace[trace["iou"].notna()] if "iou" in trace else trace.iloc[:0]
    fig, axes = plt.subplots(1 + (not iou.empty), len(xs), figsize=(4.6 * len(xs), 2.6 * (1 + (not iou.empty))),
                             squeeze=False)
    for ax, (x, name) in zip(axes[-1] if not iou.empty else [], xs):
        ax.plot(iou[x], iou["iou"], "o-", ms=4, color="tab:green")
        for _, r in iou.iterrows():
            ax.annotate(r["stage"], (r[x], r["iou"]), fontsize=6, xytext=(2, -8), textcoords="offset points")
        ax.set_xlabel(name)
        ax.set_ylabel("input-view IoU")
        ax.grid(alpha=0.3)
    groups = trace.groupby(["stage", "res"], sort=False) if "stage" in trace else trace.groupby("level")
    for ax, (x, name) in zip(axes[0], xs):
        for key, part in groups:
            ax.plot(part[x], part["loss"], ".", ms=2, label=f"{key[0]} {key[1]}px" if "stage" in trace
                    else f"GA level {key}")
        ax.plot(trace[x], trace["best"], "k-", lw=1, label="best so far")
        if (trace["loss"] > 0).all():
            ax.set_yscale("log")
        ax.set_xlabel(name)
        ax.set_ylabel(f"{loss} loss")
        ax.grid(alpha=0.3)
    axes[0, -1].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig


def _aggregate_bars(summary: pd.DataFrame):
    """Class aggregates of the test split (mean over cases, error bar: std over seeds) of each row's
    headline: the shape IoU for a camera-withheld row (labelled so), else the world IoU."""
    from ipm.table import WORDS, scored_by

    agg = summary[summary["case"].str.contains("/", na=False) & (summary["split"] == "test")]
    bars = pd.DataFrame([{"case": line["case"], "value": line[m], "spread": line.get(f"{m}_std", np.nan),
                          "label": line["label"] if m == "iou_mean" else f"{line['label']}, {WORDS[m]} IoU"}
                         for _, line in agg.iterrows() for m in [scored_by(line["row"])]],
                        columns=["case", "label", "value", "spread"])
    if bars["value"].isna().all():
        return None
    wide = bars.pivot_table(index="case", columns="label", values="value", aggfunc="first")
    err = bars.pivot_table(index="case", columns="label", values="spread", aggfunc="first").reindex_like(wide)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    wide.plot.bar(ax=ax, rot=0, width=0.8, yerr=err.fillna(0.0), capsize=2)
    ax.set_ylim(max(0.0, float(np.nanmin(wide.to_numpy())) - 0.05), 1.0)
    ax.set_ylabel("64-view IoU, mean over cases")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(axis="y", alpha=0.3)
    return fig
