"""Benchmark: wall time and 64-view IoU of the instant-NGP-style baseline per case and view count.

    .venv/bin/python bench/ngp_speed.py [--threads 2] [--profile default] [--cases cup_1]
        [--views 16 64] [--seed 0] [--synth DIR] [--out results/bench/ngp_speed.json]

Renders each case's hemisphere views (256 px, as the workflow does) into ``--synth`` (kept and
reused when given, else a temporary folder), runs ``run_ngp`` on each, scores the mesh with
``ipm.metrics.evaluate.evaluate_files`` and writes the numbers as JSON with the machine's
description. The paper's instant-NGP scored 0.858 (cup_1, 16 views) and 0.905 (64 views).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--profile", default="default")
    ap.add_argument("--cases", nargs="+", default=["cup_1"])
    ap.add_argument("--views", nargs="+", type=int, default=[16, 64])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--synth", default=None, help="folder for the rendered views (kept; reused if present)")
    ap.add_argument("--out", default="results/bench/ngp_speed.json")
    args = ap.parse_args()

    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant

    configure_threads(args.threads)
    set_mitsuba_variant("cpu", args.threads)
    from baselines.ngp import run_ngp
    from ipm.metrics.evaluate import evaluate_files
    from ipm.synth import synthesize

    record = {"machine": machine_info(args.threads), "load_average": os.getloadavg(), "threads": args.threads,
              "profile": args.profile, "seed": args.seed, "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        synth = Path(args.synth) if args.synth else Path(tmp) / "synth"
        for case in args.cases:
            for n in args.views:
                views = synth / case / f"hemi{n}"
                if not views.exists():
                    synthesize(case, views, n_views=n, res=256, layout="hemi", progress=False)
                out = Path(tmp) / "out" / case / f"ngp_{n}"
                t0 = time.perf_counter()
                info = run_ngp(views / "transforms.json", out, profile=args.profile, seed=args.seed, progress=False)
                seconds = time.perf_counter() - t0
                m = evaluate_files(views / "reference.ply", out / "mesh.ply", Path(tmp) / f"{case}_{n}.json")
                run = {"seconds": seconds, "train_seconds": info["train_seconds"], "final_loss": info["final_loss"],
                       "iou_mean": m["iou_mean"], "iou_min": m["iou_min"], "viou": m["viou"],
                       "chamfer_l2": m["chamfer_l2"], "shape_iou": m.get("shape_iou")}
                record["runs"][f"{case}/{n}"] = run
                print(f"{case:10s} {n:3d} views: {seconds:6.1f} s (training {info['train_seconds']:.1f} s)  "
                      f"IoU {run['iou_mean']:.4f}, vIoU {run['viou']:.3f}", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"written {out}")


if __name__ == "__main__":
    main()
