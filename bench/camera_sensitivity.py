"""Benchmark of the scoring, not of a method: the 64-view world IoU a camera-withheld result loses
to its camera's error alone. Each case's exact reference shape is placed where the camera-withheld
row's registration would put it had the fit found the shape exactly and the camera's pitch or field
of view wrong by the amounts given (``ipm.photo.misplaced``: the foot pixel's ray meets the ground
elsewhere, the object keeps its size in the image), and scored against itself.

    .venv/bin/python bench/camera_sensitivity.py [--cases cup_1 cup_2 building_1] [--pitch 0.25 0.5 1 3]
        [--fov 0.02 0.05 0.1 -0.1] [--threads 2] [--out results/bench/camera_sensitivity.json]

Prints one row per case (IoU per error; pitch in degrees, down; field of view relative) and the mean,
and writes them as JSON. How to read a camera-withheld row's world IoU against the known camera's.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["cup_1", "cup_2", "building_1"])
    ap.add_argument("--pitch", nargs="+", type=float, default=[0.25, 0.5, 1.0, 3.0], help="pitch errors (degrees)")
    ap.add_argument("--fov", nargs="+", type=float, default=[0.02, 0.05, 0.1, -0.1],
                    help="relative field-of-view errors")
    ap.add_argument("--input-res", type=int, default=256, help="width of the synthesized input view")
    ap.add_argument("--views", type=int, default=64)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="results/bench/camera_sensitivity.json")
    args = ap.parse_args()

    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant

    configure_threads(args.threads)
    set_mitsuba_variant("cpu", args.threads)
    import numpy as np

    from ipm.io import load_mesh, load_views, write_json
    from ipm.metrics.silhouette import silhouette_iou
    from ipm.photo import misplaced
    from ipm.problem import foot_pixel
    from ipm.synth import synthesize

    errors = [(p, 0.0) for p in args.pitch] + [(0.0, f) for f in args.fov]
    names = [f"pitch {p:+g} deg" if p else f"fov {f:+.0%}" for p, f in errors]
    record = {"machine": machine_info(args.threads), "threads": args.threads, "input_res": args.input_res,
              "errors": names, "iou": {}}
    print(f"{'case':14s}" + "".join(f"{n:>16s}" for n in names), flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            synthesize(case, Path(tmp) / case, n_views=1, res=args.input_res, spp=32, progress=False)
            views = load_views(Path(tmp) / case / "transforms.json")
            reference = load_mesh(Path(tmp) / case / "reference.ply")
            foot = foot_pixel(views.masks[0])
            row = []
            for pitch, fov in errors:
                moved = reference.copy()
                moved.vertices = misplaced(reference.vertices, views.c2w[0], views.fov_x, views.width, views.height,
                                           foot, np.radians(pitch), fov)
                row.append(float(silhouette_iou(reference, moved, args.views, args.res)["iou_mean"]))
            record["iou"][case] = row
            print(f"{case:14s}" + "".join(f"{v:16.3f}" for v in row), flush=True)
    mean = np.mean(list(record["iou"].values()), axis=0)
    record["mean"] = mean.tolist()
    print(f"{'mean':14s}" + "".join(f"{v:16.3f}" for v in mean))
    write_json(args.out, record)  # atomically, its folder made


if __name__ == "__main__":
    main()
