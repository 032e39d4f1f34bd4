"""The HTML report: Table 1, all metrics, IoU bars, per-case pictures and optimisation traces.

Self-contained (images inlined as base64) so the page can be mailed or archived as one file.
"""
from __future__ import annotations

import base64
import html
import io
import json
import os
import platform
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from ipm.io.atomic import atomic_path  # noqa: E402

_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:0.9em}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}img{max-width:100%}
.case{border-top:2px solid #ddd;margin-top:2em}.note{color:#666;font-size:0.9em}
img.input{width:240px;image-rendering:pixelated}"""


def _img(path: Path | None = None, fig=None, cls: str = "") -> str:
    if fig is not None:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
        plt.close(fig)
        data = buf.getvalue()
    elif path is not None and path.exists():
        data = path.read_bytes()
    else:
        return '<span class="note">(missing)</span>'
    return f'<img class="{cls}" src="data:image/png;base64,{base64.b64encode(data).decode()}">'


def _iou_bars(df: pd.DataFrame):
    wide = df.pivot_table(index="case", columns="label", values="iou_mean", aggfunc="first")
    fig, ax = plt.subplots(figsize=(8, 3.2))
    wide.plot.bar(ax=ax, rot=0, width=0.8)
    lo = max(0.0, float(wide.min().min()) - 0.05)
    ax.set_ylim(lo, 1.0)
    ax.set_ylabel("64-view silhouette IoU")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(axis="y", alpha=0.3)
    return fig


def _trace_plot(trace: pd.DataFrame, loss: str = "silhouette"):
    """Loss per evaluation: the diff path's stages and resolutions, or the GA's tree levels
    (leaves 0, root highest) with the best so far."""
    fig, ax = plt.subplots(figsize=(6, 2.6))
    if "stage" in trace:
        for (stage, res), part in trace.groupby(["stage", "res"], sort=False):
            ax.plot(part["eval"], part["loss"], ".", ms=2, label=f"{stage} {res}px")
    else:
        for level, part in trace.groupby("level"):
            ax.plot(part["eval"], part["loss"], ".", ms=2, label=f"GA level {level}")
        ax.plot(trace["eval"], trace["best"], "k-", lw=1, label="best")
    ax.set_yscale("log")
    ax.set_xlabel("evaluation")
    ax.set_ylabel(f"{loss} loss")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return fig


def build_report(table_csv: str, wide_csv: str, metrics: list[str], out_html: str, config: dict,
                 input_dirs: dict | None = None) -> None:
    """Write ``out_html`` from the table and the per-case result folders; ``input_dirs`` maps a
    case to the folder of its input views (relative to the working directory)."""
    df = pd.read_csv(table_csv)
    wide = pd.read_csv(wide_csv, index_col=0)
    results = Path(table_csv).parent
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>IPM-Bench report</title>"
             f"<style>{_CSS}</style></head><body><h1>IPM-Bench report</h1>",
             f"<p class='note'>profile <b>{html.escape(str(config.get('profile')))}</b>, seed {config.get('seed')}, "
             f"cases {', '.join(config.get('cases', []))}; machine {html.escape(platform.platform())}, "
             f"{os.cpu_count()} CPUs. IoU: mean over {config.get('evaluate', {}).get('views')} Fibonacci-sphere "
             f"views (DESIGN.md); reference lines are computed from the reference itself.</p>",
             "<h2>Table 1: mean silhouette IoU</h2>", wide.to_html(float_format="%.3f", na_rep="-"),
             _img(fig=_iou_bars(df)), "<h2>All metrics</h2>",
             df.drop(columns=["row", "kind"]).to_html(index=False, float_format="%.4f", na_rep="-"),
             "<h2>Wall time per method</h2><p class='note'>seconds per reconstruction, one thread each, "
             "mean over cases</p>",
             df.groupby("label", sort=False)["seconds"].agg(["mean", "min", "max"]).to_html(float_format="%.1f")]
    for case in config.get("cases", []):
        parts.append(f"<div class='case'><h2>{html.escape(case)}</h2>")
        synth = Path((input_dirs or {}).get(case, results / "synth" / case))
        parts.append("<p>input view and its mask</p>" + _img(synth / "rgb" / "000.png", cls="input") + " "
                     + _img(synth / "masks" / "000.png", cls="input"))
        for row in df[df["case"] == case].itertuples():
            folder = results / "evaluate" / row.row / case
            if isinstance(row.note, str) and row.note.startswith("failed"):
                parts.append(f"<h3>{html.escape(row.label)}: - ({html.escape(row.note)})</h3>")
                continue
            note = f" ({html.escape(row.note)})" if isinstance(row.note, str) and row.note else ""
            parts.append(f"<h3>{html.escape(row.label)}: IoU {row.iou_mean:.3f}, volumetric IoU {row.viou:.3f}{note}</h3>")
            parts.append(_img(folder / "preview.png"))
            recon = results / "reconstruct" / row.row / case
            if (recon / "parts.png").exists():
                parts.append("<p class='note'>reference (top) and reconstruction (bottom), one colour per part</p>"
                             + _img(recon / "parts.png"))
            info = json.loads((recon / "params.json").read_text()) if (recon / "params.json").exists() else None
            if (recon / "trace.csv").exists():
                loss = (info or {}).get("loss", "silhouette")
                parts.append(_img(fig=_trace_plot(pd.read_csv(recon / "trace.csv"), loss)))
            if info is not None:
                pose = {k: (round(v, 3) if isinstance(v, float) else [round(x, 3) for x in v])
                        for k, v in info["pose"].items()}
                extra = [f"{k} {info['params'][k]}" for k in ("has_handle",) if k in info["params"]]
                if "branch_graph_vertices" in info:
                    extra.append(f"branch graph {info['branch_graph_vertices']} vertices")
                parts.append(f"<p class='note'>pose {html.escape(json.dumps(pose))}; "
                             + "".join(f"{html.escape(e)}; " for e in extra)
                             + f"{info['evaluations']} evaluations, final loss {info['final_loss']:.5f}</p>")
        parts.append("</div>")
    parts.append("</body></html>")
    with atomic_path(out_html) as tmp:
        tmp.write_text("\n".join(parts))
