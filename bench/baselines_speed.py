"""Benchmark: wall time and 64-view IoU of every baseline per case and view count.

    .venv/bin/python bench/baselines_speed.py [--threads 1] [--profile default]
        [--cases cup_1 cup_2 cup_ext] [--out results/bench/baselines_speed.json]

Renders the views each baseline reads (hemisphere sets at 256 px, rings at 512 px), runs the
baselines with the view counts of the paper's Table 1, and writes the numbers as JSON with the
machine's description. A failed run (COLMAP registering too few images) is recorded with its reason.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

VIEW_COUNTS = {"diffsdf": (2, 6, 12), "visual_hull": (2, 6, 12), "colmap_known": (16, 64), "colmap_sfm": (16, 64)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--profile", default="default")
    ap.add_argument("--cases", nargs="+", default=["cup_1", "cup_2", "cup_ext"])
    ap.add_argument("--methods", nargs="+", default=list(VIEW_COUNTS))
    ap.add_argument("--out", default="results/bench/baselines_speed.json")
    args = ap.parse_args()

    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant

    configure_threads(args.threads)
    set_mitsuba_variant("cpu", args.threads)
    from ipm.io import load_mesh
    from ipm.methods import METHODS
    from ipm.metrics import evaluate_meshes
    from ipm.synth import synthesize

    record = {"machine": machine_info(args.threads), "threads": args.threads, "profile": args.profile, "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for case in args.cases:
            for name in args.methods:
                layout = METHODS[name].layout
                for n in VIEW_COUNTS[name]:
                    views = tmp / case / f"{layout}{n}"
                    if not views.exists():
                        synthesize(case, views, n_views=n, res=512 if layout == "ring" else 256,
                                   layout=layout, progress=False)
                    out = tmp / "out" / case / f"{name}_{n}"
                    t0 = time.perf_counter()
                    info = METHODS[name](views / "transforms.json", out, profile=args.profile, progress=False)
                    run = {"seconds": time.perf_counter() - t0, "failed": info.get("failed"), "note": info.get("note")}
                    if not info.get("failed"):
                        m = evaluate_meshes(load_mesh(views / "reference.ply"), load_mesh(out / "mesh.ply"))
                        run.update(iou_mean=m["iou_mean"], viou=m["viou"], chamfer_l2=m["chamfer_l2"])
                    record["runs"][f"{case}/{name}/{n}"] = run
                    iou = f"IoU {run['iou_mean']:.4f}, vIoU {run['viou']:.3f}" if "iou_mean" in run else f"- ({run['failed']})"
                    print(f"{case:8s} {name:13s} {n:3d} views: {run['seconds']:7.1f} s  {iou}", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"written {out}")


if __name__ == "__main__":
    main()
