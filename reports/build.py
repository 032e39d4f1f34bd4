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
import numpy as np  # noqa: E402
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


def _summary_html(summary: pd.DataFrame, split: str, metric: str) -> str:
    """Per class: rows x (cases, aggregates) of ``metric`` as mean ± std (worst) over seeds."""
    from ipm.table import table_blocks

    blocks = table_blocks(summary[summary["split"] == split], metric)
    if not blocks:
        return "<p class='note'>(no cases in this split)</p>"
    return "\n".join(f"<h3>{html.escape(title)}</h3><table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in head)
                     + "</tr>" + "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
                     + "</table>" for title, head, rows in blocks)


def _aggregate_bars(summary: pd.DataFrame):
    """Class aggregates of the test split (mean over cases, error bar: std over seeds)."""
    agg = summary[summary["case"].str.contains("/", na=False) & (summary["split"] == "test")]
    if agg.empty:
        return None
    wide = agg.pivot_table(index="case", columns="label", values="iou_mean", aggfunc="first")
    err = agg.pivot_table(index="case", columns="label", values="iou_mean_std", aggfunc="first").reindex_like(wide)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    wide.plot.bar(ax=ax, rot=0, width=0.8, yerr=err.fillna(0.0), capsize=2)
    ax.set_ylim(max(0.0, float(np.nanmin(wide.to_numpy())) - 0.05), 1.0)
    ax.set_ylabel("64-view IoU, mean over cases")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(axis="y", alpha=0.3)
    return fig


def build_report(table_csv: str, wide_csv: str, metrics: list[str], out_html: str, config: dict,
                 input_dirs: dict | None = None, summary_csv: str | None = None) -> None:
    """Write ``out_html`` from the tables and the per-case result folders; ``input_dirs`` maps a
    case to the folder of its input views (relative to the working directory)."""
    from ipm.table import summary_table

    df = pd.read_csv(table_csv)
    summary = pd.read_csv(summary_csv) if summary_csv else summary_table(df)
    results = Path(table_csv).parent
    splits = df.drop_duplicates("case").groupby("split", sort=False)["case"].apply(list).to_dict()
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>IPM-Bench report</title>"
             f"<style>{_CSS}</style></head><body><h1>IPM-Bench report</h1>",
             f"<p class='note'>profile <b>{html.escape(str(config.get('profile')))}</b>, seeds "
             f"{', '.join(map(str, config.get('seeds', [])))}; "
             + "; ".join(f"{html.escape(k)} cases: {', '.join(map(html.escape, v))}" for k, v in splits.items())
             + f"; report built on {html.escape(platform.platform())}, {os.cpu_count()} CPUs. IoU: mean over "
             f"{config.get('evaluate', {}).get('views')} Fibonacci-sphere views (DESIGN.md); reference lines are "
             "computed from the reference itself. The <b>test</b> split is scored, never tuned on; the <b>dev</b> "
             "split is where defaults were chosen.</p>",
             "<h2>Table 1: 64-view silhouette IoU, test split</h2><p class='note'>mean ± standard deviation over "
             "seeds (worst seed); aggregates (class/split/family: in = made by the class's generator, out = built by "
             "independent code): mean over the cases ± standard deviation over seeds of that mean (worst case)</p>",
             _summary_html(summary, "test", "iou_mean")]
    fig = _aggregate_bars(summary)
    if fig is not None:
        parts.append(_img(fig=fig))
    parts += ["<h2>Shape IoU after the best similarity alignment, test split</h2><p class='note'>the same "
              "64-view IoU after turning, moving and scaling the reconstruction onto the reference: what is left "
              "is the shape's error, the rest of the gap to the world-frame IoU is placement</p>",
              _summary_html(summary, "test", "shape_iou"),
              "<h2>Dev split (defaults were tuned here)</h2>", _summary_html(summary, "dev", "iou_mean"),
              _summary_html(summary, "dev", "shape_iou")]
    rec = summary[summary["param_err"].notna() & ~summary["case"].str.contains("/", na=False)]
    if not rec.empty:
        cols = ["label", "split", "case", "n_seeds", "param_err", "param_err_max", "discrete_match", "counts_exact",
                "yaw_err_deg", "trans_err_rel", "size_err_pct"]
        parts += ["<h2>Parameter recovery (in-family cases)</h2><p class='note'>means over seeds: unit-cube error of "
                  "the continuous parameters (mean, largest), share of discrete parameters recovered, share of runs "
                  "with every count the input view shows exact (buildings: storeys, windows per facade seen), yaw error "
                  "(degrees; - for objects that look the same turned), translation error / reference height, scale "
                  "error (%)</p>", rec[cols].to_html(index=False, float_format="%.3f", na_rep="-")]
    parts += ["<h2>Wall time per method</h2><p class='note'>seconds per reconstruction, one thread each, "
              "mean over cases and seeds</p>",
              df.groupby("label", sort=False)["seconds"].agg(["mean", "min", "max"]).to_html(float_format="%.1f"),
              "<details><summary>All runs, all metrics</summary>",
              df.drop(columns=["row", "kind"]).to_html(index=False, float_format="%.4f", na_rep="-"), "</details>"]
    for case in config.get("cases", []):
        runs = df[df["case"] == case]
        split = runs["split"].iloc[0] if len(runs) else "?"
        parts.append(f"<div class='case'><h2>{html.escape(case)} <span class='note'>({html.escape(split)})</span></h2>")
        synth = Path((input_dirs or {}).get(case, results / "synth" / case))
        parts.append("<p>input view and its mask</p>" + _img(synth / "rgb" / "000.png", cls="input") + " "
                     + _img(synth / "masks" / "000.png", cls="input"))
        for (row, label), g in runs.groupby(["row", "label"], sort=False):
            per_seed = ", ".join(f"seed {int(r.seed)}: " + ("-" if pd.isna(r.iou_mean) else f"{r.iou_mean:.3f}")
                                 for r in g.itertuples())
            first = g.iloc[0]
            seed_dir = f"s{int(first['seed'])}"
            folder = results / "evaluate" / row / case / seed_dir
            if isinstance(first["note"], str) and first["note"].startswith("failed"):
                parts.append(f"<h3>{html.escape(label)}: - ({html.escape(first['note'])})</h3>")
                continue
            note = f" ({html.escape(first['note'])})" if isinstance(first["note"], str) and first["note"] else ""
            shape = "" if pd.isna(first.get("shape_iou")) else f", shape IoU {first['shape_iou']:.3f}"
            parts.append(f"<h3>{html.escape(label)}: IoU {per_seed}{note}</h3><p class='note'>pictures of seed "
                         f"{int(first['seed'])}: IoU {first['iou_mean']:.3f}{shape}, volumetric IoU "
                         f"{first['viou']:.3f}</p>")
            parts.append(_img(folder / "preview.png"))
            recon = results / "reconstruct" / row / case / seed_dir
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
