"""Benchmark: what a wrong mask costs. Each case's input view (256 px) is fitted by ours with its
true mask and with the mask degraded by known amounts (``ipm.degrade.DEGRADATIONS``: the edge moved
in or out by 1, 2 and 4 px, a ragged edge, a hole, a thin part lost); every fit is scored as the
default run scores it (64 views), and the loss against the true mask's fit is reported per case
and degradation, with a plot of shape IoU against the edge's shift per class.

    .venv/bin/python bench/mask_robustness.py [--cases cup_1 cup_2 building_d11] [--seeds 0]
        [--jobs 2] [--out results/bench/mask_robustness]

A fit runs as ``ipm reconstruct`` on one thread, ``--jobs`` at a time. Tune nothing on what it
prints for test cases: run it on dev cases (the defaults) to choose, on test cases to report.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np


def degraded_views(src: Path, dst: Path, name: str, seed: int) -> tuple[Path, float]:
    """A copy of the views folder ``src`` whose mask is degraded by ``name`` (seeded), and the
    degraded mask's IoU with the true one (``ipm.degrade.degrade_views``)."""
    from ipm.degrade import degrade_views

    return dst, degrade_views(src, dst, name, seed)[0]


def fit_and_score(generator: str, views: Path, reference: Path, out: Path, seed: int) -> dict:
    """``ipm reconstruct`` on one thread, then the default run's metrics of its mesh."""
    from ipm.metrics.evaluate import evaluate_files

    subprocess.run([sys.executable, "-m", "ipm.cli", "reconstruct", "--generator", generator, "--views",
                    str(views / "transforms.json"), "--out", str(out), "--threads", "1", "--seed", str(seed),
                    "--quiet"], check=True, capture_output=True)
    m = evaluate_files(reference, out / "mesh.ply", out / "metrics.json")
    return {"world_iou": round(float(m["iou_mean"]), 4), "shape_iou": round(float(m["shape_iou"]), 4),
            "seconds": round(float(json.loads((out / "timing.json").read_text())["seconds"]), 1)}


def with_losses(rows: list[dict]) -> list[dict]:
    """Each row given its loss of shape and world IoU against the same case and seed's fit to the
    true mask (``shape_loss``, ``world_loss``; positive: the degraded mask's fit is worse)."""
    clean = {(r["case"], r["seed"]): r for r in rows if r["degradation"] == "none"}
    for r in rows:
        base = clean[r["case"], r["seed"]]
        r["shape_loss"] = round(base["shape_iou"] - r["shape_iou"], 4)
        r["world_loss"] = round(base["world_iou"] - r["world_iou"], 4)
    return rows


def plot(rows: list[dict], path: Path) -> None:
    """Shape IoU against the edge's shift (pixels), one line per case, a panel per class."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ipm.degrade import edge_shift

    classes = sorted({r["generator"] for r in rows})
    fig, axes = plt.subplots(1, len(classes), figsize=(4.5 * len(classes), 3.4), squeeze=False)
    for ax, generator in zip(axes[0], classes):
        for case in sorted({r["case"] for r in rows if r["generator"] == generator}):
            pts = sorted((edge_shift(r["degradation"]), r["shape_iou"]) for r in rows
                         if r["case"] == case and edge_shift(r["degradation"]) is not None)
            xs = sorted({p for p, _ in pts})
            ax.plot(xs, [np.mean([v for p, v in pts if p == x]) for x in xs], "o-", label=case)
        ax.set(title=generator, xlabel="mask edge moved (px at 256 px; - inwards)", ylabel="shape IoU (64 views)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["cup_1", "cup_2", "building_d11"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--degradations", nargs="+", default=None, help="names of ipm.degrade.DEGRADATIONS (default: all)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="results/bench/mask_robustness")
    args = ap.parse_args()
    from ipm.cases import case_split
    from ipm.degrade import DEGRADATIONS
    from ipm.io import write_json
    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant
    from ipm.cases import load_case
    from ipm.synth import synthesize

    configure_threads(1, "cpu")
    set_mitsuba_variant("cpu", 1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        jobs = []
        for case in args.cases:
            truth = load_case(case)
            src = Path(tmp) / case / "views"
            synthesize(case, src, n_views=1, res=256, spp=32, progress=False)
            for seed in args.seeds:
                for name in dict.fromkeys(["none", *(args.degradations or DEGRADATIONS)]):
                    tag = f"{case}-s{seed}-{name.replace(' ', '_')}"
                    views, mask_iou = degraded_views(src, Path(tmp) / "views" / tag, name, seed)
                    jobs.append(({"case": case, "split": case_split(truth), "generator": truth["generator"],
                                  "seed": seed, "degradation": name, "mask_iou": round(mask_iou, 4)},
                                 (truth["generator"], views, src / "reference.ply", Path(tmp) / "fits" / tag, seed)))
        with ThreadPoolExecutor(args.jobs) as pool:
            results = pool.map(lambda job: {**job[0], **fit_and_score(*job[1])}, jobs)
            for row in results:
                rows.append(row)
                print(f"{row['case']} s{row['seed']} {row['degradation']:>15s}: mask IoU {row['mask_iou']:.3f}, "
                      f"shape IoU {row['shape_iou']:.3f}, world IoU {row['world_iou']:.3f} ({row['seconds']:.0f} s)",
                      flush=True)
    with_losses(rows)
    write_json(out / "mask_robustness.json", {"machine": machine_info(1), "jobs": args.jobs, "rows": rows})
    plot(rows, out / "mask_robustness.png")
    print(f"wrote {out / 'mask_robustness.json'} and {out / 'mask_robustness.png'}")


if __name__ == "__main__":
    main()
