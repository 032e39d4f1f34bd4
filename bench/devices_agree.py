"""Check: the silhouette renderers give the same images, losses and gradients on CPU and GPU.

One machine writes its numbers for a case folder made by ``ipm synth`` (both machines must read
the same folder: the references are rendered too, and differ in the last bits between backends);
the other recomputes them and compares:

    .venv/bin/python bench/devices_agree.py --case DIR --device cuda --out gpu.npz      # GPU machine
    .venv/bin/python bench/devices_agree.py --case DIR --against gpu.npz                # here, CPU

For each renderer (jax, mitsuba) and width: the silhouette of the generator's first preset in the
case's first view (the start of a reconstruction), its loss and its gradient with respect to the
parameters (render seed 0). Compared: pixels whose coverage differs by more than 0.5, the largest
coverage difference, the loss's relative difference and the gradient's (norm of the difference
over the norm). Prints a table and writes the numbers as JSON beside ``--out``'s npz.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

RENDERERS = ("jax", "mitsuba")


def compute(case: Path, widths: list[int], profile: str) -> dict:
    """{"<renderer>/<width>/<image|loss|grad>": array} of the case's first view at the preset start."""
    import numpy as np

    from ipm.generators import get_generator
    from ipm.io import load_views
    from ipm.search.objective import Objective
    from ipm.problem import Problem, estimate_anchor
    from ipm.profiles import get_profile

    gen = get_generator(json.loads((case / "ground_truth.json").read_text())["generator"])
    views = load_views(case / "transforms.json")
    problem = Problem(gen, *estimate_anchor(views))
    z = problem.initial_z(gen.spec.to_unit(next(iter(gen.presets.values()))), 0.5)
    lod = max(1, gen.min_fit_lod)
    out = {"z": z}
    for renderer in RENDERERS:
        prof = get_profile(profile, renderer=renderer).objective
        for width in widths:
            objective = Objective(problem, views, width, lod, prof)
            loss, grad = objective(z, seed=0)
            out[f"{renderer}/{width}/image"] = np.asarray(objective._render(z), np.float32)  # noqa: SLF001
            out[f"{renderer}/{width}/loss"] = np.float64(loss)
            out[f"{renderer}/{width}/grad"] = np.asarray(grad, np.float64)
    return out


def compare(here: dict, there: dict) -> list[dict]:
    """One row per renderer and width: how far ``here`` is from ``there``."""
    import numpy as np

    rows = []
    for key in sorted(k for k in there if k.endswith("/image")):
        renderer, width, _ = key.split("/")
        a, b = here[key], there[key]
        ga, gb = here[f"{renderer}/{width}/grad"], there[f"{renderer}/{width}/grad"]
        la, lb = float(here[f"{renderer}/{width}/loss"]), float(there[f"{renderer}/{width}/loss"])
        rows.append({"renderer": renderer, "width": int(width), "pixels": int(a.size),
                     "pixels_differ": int((np.abs(a - b) > 0.5).sum()),
                     "max_coverage_diff": float(np.abs(a - b).max()),
                     "loss_rel_diff": abs(la - lb) / max(abs(lb), 1e-12),
                     "grad_rel_diff": float(np.linalg.norm(ga - gb) / max(np.linalg.norm(gb), 1e-12))})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", required=True, type=Path, help="a folder written by `ipm synth`")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--profile", default="default")
    ap.add_argument("--widths", nargs="+", type=int, default=[128, 256])
    ap.add_argument("--out", type=Path, help="write this machine's numbers here (npz)")
    ap.add_argument("--against", type=Path, help="compare with numbers another machine wrote (npz)")
    args = ap.parse_args()

    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant

    configure_threads(args.threads, args.device)
    variant = set_mitsuba_variant(args.device, args.threads).variant()
    import jax
    import numpy as np

    here = compute(args.case, args.widths, args.profile)
    machine = {"machine": machine_info(device=args.device), "device": args.device, "jax_backend": jax.default_backend(),
               "mitsuba_variant": variant}
    print(json.dumps(machine))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        np.savez(args.out, **here)
        args.out.with_suffix(".json").write_text(json.dumps(machine, indent=2) + "\n")
    if args.against:
        rows = compare(here, dict(np.load(args.against)))
        print(f"{'renderer':8s} {'width':>5s} {'pixels differ':>14s} {'max cov diff':>12s} "
              f"{'loss rel':>9s} {'grad rel':>9s}")
        for r in rows:
            print(f"{r['renderer']:8s} {r['width']:5d} {r['pixels_differ']:7d}/{r['pixels']:<6d} "
                  f"{r['max_coverage_diff']:12.4f} {r['loss_rel_diff']:9.2e} {r['grad_rel_diff']:9.2e}")
        if args.out:
            args.out.with_name(args.out.stem + "_compare.json").write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
