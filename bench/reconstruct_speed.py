"""Benchmark: silhouette loss-and-gradient time per renderer and resolution, and
whole single-view reconstructions of the given cases with each renderer (cups by default;
buildings: ``--cases building_1 ...``) with their 64-view IoU, all in one run so the renderers'
ratio is measured on the same machine at the same time.

    .venv/bin/python bench/reconstruct_speed.py [--device cpu|cuda] [--threads 2] [--profile default]
        [--renderers jax mitsuba] [--cases cup_1 cup_2 cup_ext] [--resolutions 64 128 256 512]
        [--out results/bench/reconstruct_speed.json]
        [--keep DIR] [--no-eval] [--input-res 256]

Iterations: one loss and gradient of the first case's input view at the refinement level of detail
(render + backward). ``--no-eval`` skips the 64-view IoU (it needs open3d, which the GPU machine
lacks); ``--keep DIR`` keeps each case's reference and reconstructions there, for ``ipm evaluate``
on another machine. Prints a table and writes the numbers as JSON (with the machine's description).
Targets it checks: a default-profile cup or building within 5 minutes on 2 CPU cores; the JAX
renderer's cup at most 0.4 x the Mitsuba path's time.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path


def gpu_name() -> str | None:
    """The first GPU's name from ``nvidia-smi`` (None where it cannot be asked)."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=30, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return out.splitlines()[0].strip() if out.strip() else None


def _timed(fn, iterations: int, warmup: int = 3) -> float:
    """Mean milliseconds of ``fn()`` over ``iterations`` calls after ``warmup`` (compilation)."""
    for _ in range(warmup):
        fn()
    t0 = time.perf_counter()
    for _ in range(iterations):
        fn()
    return 1000 * (time.perf_counter() - t0) / iterations


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--profile", default="default")
    ap.add_argument("--renderers", nargs="+", default=["jax", "mitsuba"], choices=["jax", "mitsuba"])
    ap.add_argument("--cases", nargs="+", default=["cup_1", "cup_2", "cup_ext"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="one reconstruction per case and seed")
    ap.add_argument("--resolutions", nargs="+", type=int, default=[64, 128, 256, 512])
    ap.add_argument("--iterations", type=int, default=20, help="timed iterations per resolution")
    ap.add_argument("--input-res", type=int, default=256,
                    help="width of the synthesized input view (the default DAG's synth res)")
    ap.add_argument("--out", default="results/bench/reconstruct_speed.json")
    ap.add_argument("--keep", help="copy references and reconstructions into this folder")
    ap.add_argument("--no-eval", action="store_true", help="skip the IoU (no open3d needed)")
    ap.add_argument("--compile-cache", action="store_true",
                    help="keep JAX's persistent compilation cache on (default off: every compilation timed)")
    args = ap.parse_args()
    if not args.compile_cache:
        os.environ["IPM_JAX_CACHE"] = "off"

    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant

    configure_threads(args.threads, args.device)
    set_mitsuba_variant(args.device, args.threads)
    import numpy as np

    from ipm.generators import get_generator
    from ipm.io import load_mesh, load_views
    from ipm.methods import METHODS
    from ipm.search.objective import Objective
    from ipm.problem import Problem, estimate_anchor
    from ipm.profiles import get_profile
    from ipm.synth import synthesize

    record = {"machine": machine_info(args.threads), "gpu": gpu_name() if args.device == "cuda" else None,
              "device": args.device, "threads": args.threads, "profile": args.profile, "input_res": args.input_res,
              "compile_cache": args.compile_cache,
              "iteration_ms": {r: {} for r in args.renderers},
              "reconstructions": {r: {} for r in args.renderers}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for case in args.cases:
            synthesize(case, tmp / case, n_views=1, res=args.input_res, spp=32, progress=False)
        generators = {case: json.loads((tmp / case / "ground_truth.json").read_text())["generator"]
                      for case in args.cases}
        views = load_views(tmp / args.cases[0] / "transforms.json")
        gen = get_generator(generators[args.cases[0]])
        lod = max(1, gen.min_fit_lod)
        problem = Problem(gen, *estimate_anchor(views))
        z = problem.initial_z(gen.spec.to_unit(next(iter(gen.presets.values()))), 0.5)
        for renderer in args.renderers:
            prof = get_profile(args.profile, renderer=renderer).objective
            for res in args.resolutions:
                objective = Objective(problem, views, res, lod, prof)
                ms = _timed(lambda: objective(z), args.iterations)
                record["iteration_ms"][renderer][res] = ms
                print(f"{renderer:8s} iteration at {res:4d} px (render + backward, {gen.name} lod {lod}): "
                      f"{ms:8.1f} ms", flush=True)
        for case in args.cases:
            for seed in args.seeds:
                for renderer in args.renderers:
                    out = tmp / f"rec_{case}_{renderer}_s{seed}"
                    t0 = time.perf_counter()
                    info = METHODS["diff"](tmp / case / "transforms.json", out, generator=generators[case],
                                           profile=args.profile, seed=seed, progress=False, renderer=renderer)
                    seconds = time.perf_counter() - t0
                    if args.keep:
                        keep = Path(args.keep) / case
                        keep.mkdir(parents=True, exist_ok=True)
                        shutil.copy(tmp / case / "reference.ply", keep / "reference.ply")
                        for name in ("mesh.ply", "params.json", "trace.csv", "timing.json"):
                            shutil.copy(out / name, keep / f"{renderer}_seed{seed}_{name}")
                    spec = get_generator(generators[case]).spec
                    discrete = {name: info["params"][name] for name, d in zip(spec.names, spec.discrete) if d}
                    row = {"seconds": seconds, "evaluations": info["evaluations"], "discrete": discrete}
                    text = f"{case:8s} seed {seed} {renderer:8s}: {seconds:7.1f} s, {info['evaluations']} evaluations"
                    if not args.no_eval:
                        from ipm.metrics import evaluate_meshes

                        m = evaluate_meshes(load_mesh(tmp / case / "reference.ply"), load_mesh(out / "mesh.ply"))
                        row.update(iou_mean=m["iou_mean"], viou=m["viou"])
                        text += f", IoU {m['iou_mean']:.4f}, volumetric IoU {m['viou']:.4f}"
                    record["reconstructions"][renderer][f"{case}/seed{seed}"] = row
                    print(f"{text}, {' '.join(f'{k}={v:g}' for k, v in discrete.items())}", flush=True)
    summary = {r: float(np.mean([v["seconds"] for v in rec.values()])) for r, rec in record["reconstructions"].items()
               if rec}
    record["mean_reconstruction_s"] = summary
    if {"jax", "mitsuba"} <= set(summary):
        record["jax_over_mitsuba"] = summary["jax"] / summary["mitsuba"]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")
    ratio = f"; jax / mitsuba {record['jax_over_mitsuba']:.2f}" if "jax_over_mitsuba" in record else ""
    print(f"written {out}; mean reconstruction " + ", ".join(f"{r} {v:.1f} s" for r, v in summary.items()) + ratio)


if __name__ == "__main__":
    main()
