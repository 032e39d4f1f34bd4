"""Benchmark: textured results. Each case is synthesised with colour views under the reference
lighting (``ipm synth``, the hemi layout); ours reconstructs it from its first 1 and 6 views and
paints its parts from them (``ipm.texture``); each result is rendered under the same lighting and
scored against every reference view (``ipm.metrics.texture``: masked PSNR and SSIM in sRGB) on the
input views, the other views of the half of the sphere the inputs see, and those of the other half.

    .venv/bin/python bench/texture.py [--cases cup_1 cup_2] [--inputs 1 6] [--views 16] [--seeds 0]
        [--jobs 2] [--out results/bench/texture]

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

DEV = ["cup_1", "cup_2", "cup_d1", "cup_d2", "cup_d3", "cup_d4", "cup_bowl", "cup_c_mug", "cup_ext"]
IPM = [sys.executable, "-m", "ipm.cli"]


def run(args: list[str]) -> None:
    done = subprocess.run(IPM + args, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"ipm {' '.join(args)} failed:\n{done.stderr[-2000:]}")


def one(case: str, views: Path, n_input: int, seed: int, work: Path) -> dict:
    """Reconstruct ``case`` from its first ``n_input`` views and score its textured result."""
    from ipm.metrics.texture import score_result
    from ipm.synth import load_case

    out = work / f"{case}_{n_input}v_s{seed}"
    run(["reconstruct", "--generator", load_case(case)["generator"], "--views",
         str(views / "transforms.json"), "--n-input-views", str(n_input), "--seed", str(seed), "--threads", "1",
         "--out", str(out), "--quiet"])
    info = json.loads((out / "params.json").read_text())
    timing = json.loads((out / "timing.json").read_text())
    scores = score_result(out / "mesh.glb", views / "transforms.json", n_input)
    return {"case": case, "inputs": n_input, "seed": seed, "sides": scores["sides"],
            "seen_texels": info["texture"]["seen"], "seconds": timing["seconds"],
            "texture_seconds": timing.get("texture_seconds")}


def table(rows: list[dict]) -> str:
    """Markdown: a row per case and input count, PSNR / SSIM per side (mean over seeds)."""
    lines = ["| case | views in | input PSNR / SSIM | seen half | unseen half |", "|---|---|---|---|---|"]
    keys = sorted({(r["case"], r["inputs"]) for r in rows}, key=lambda k: (k[1], k[0]))
    for case, n in keys:
        mine = [r for r in rows if r["case"] == case and r["inputs"] == n]
        cells = []
        for side in ("input", "seen", "unseen"):
            got = [r["sides"][side] for r in mine if side in r["sides"]]
            cells.append(f"{np.mean([g['psnr'] for g in got]):.1f} / {np.mean([g['ssim'] for g in got]):.3f}"
                         if got else "-")
        lines.append(f"| {case} | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEV)
    ap.add_argument("--inputs", nargs="+", type=int, default=[1, 6])
    ap.add_argument("--views", type=int, default=16, help="reference views per case (the inputs among them)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="results/bench/texture")
    args = ap.parse_args()
    from ipm.runtime import configure_threads, set_mitsuba_variant

    configure_threads(1, "cpu")
    set_mitsuba_variant("cpu", 1)
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for case in args.cases:
            run(["synth", "--case", case, "--out", str(work / case), "--views", str(args.views)])
        jobs = [(c, work / c, n, s, work) for c in args.cases for n in args.inputs for s in args.seeds]
        with ThreadPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(lambda a: one(*a), jobs))
    from ipm.io.atomic import write_json

    write_json(out / "texture.json", rows)
    (out / "texture.md").write_text(table(rows) + "\n")
    print(table(rows))


if __name__ == "__main__":
    main()
