"""Benchmark: the other plans of a finished building fit laid over its footprint, refined and scored
(the measurement behind docs/results.md, "The plans laid over a fit's footprint").

For a workflow run's fit (``ROOT/results/reconstruct/diff_1v/CASE/s0``) every other plan
(rectangle, L, T, U, each with and without the annex) is laid over the extent the fit covers
(the plan move's starts, ``ipm.search.moves.plan.laid_starts``); each, and the fit itself, gets
``--steps`` Adam steps at 128 px, and all are scored at 256 px over two fixed render seeds, with
the input view's IoU and the 64-view world IoU (128 px) of the fit and of the best alternative.
Prints one line a case.

    .venv/bin/python bench/plan_alternatives.py ROOT CASE [--seed 0] [--steps 90]

One case a process: every plan compiles programs of its own, and a process that fits many
buildings' plans runs out of the compiler's code memory.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def fitted_z(problem, fit: dict) -> np.ndarray:
    """The search vector of a known-camera fit's params.json (``Problem.decode`` inverted)."""
    n, spec, pose = problem.n_shape, problem.spec, fit["pose"]
    z = np.zeros(len(problem.lower))
    z[:n] = spec.to_unit(spec.from_dict(fit["params"]))
    z[n:n + 3] = pose["yaw"], pose["tilt_x"], pose["tilt_z"]
    z[n + 3:n + 6] = (np.asarray(pose["translation"]) - problem.anchor_t) / problem.anchor_s
    z[n + 6] = np.log(pose["scale"] / problem.anchor_s)
    return z


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root")
    ap.add_argument("case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=90)
    args = ap.parse_args()
    import trimesh

    from ipm.generators import get_generator
    from ipm.io.views import load_views
    from ipm.metrics.silhouette import silhouette_iou
    from ipm.optim.memetic import Individual, adam_steps
    from ipm.problem import Problem
    from ipm.profiles import get_profile
    from ipm.search.loop import input_iou
    from ipm.search.moves.plan import laid_starts
    from ipm.search.objective import Objective
    from ipm.search.trial import scorer

    root, case, prof = Path(args.root), args.case, get_profile("default")
    gen = get_generator("buildings")
    views = load_views(root / "results" / "synth" / case / "hemi1" / "transforms.json")
    problem = Problem.for_views(gen, views, max_tilt=prof.loop.max_tilt)
    fit = json.loads((root / "results" / "reconstruct" / "diff_1v" / case / f"s{args.seed}" / "params.json").read_text())
    z = fitted_z(problem, fit)
    lod = max(prof.loop.refine_lod, gen.min_fit_lod)
    steps, score = Objective(problem, views, 128, lod, prof.objective), scorer(
        Objective(problem, views, 256, lod, prof.objective), (10_005, 10_006))
    rows = []
    for name, start in [("plan as fitted", z)] + laid_starts(problem, z):
        ind = Individual(start, problem.key(start), "plan", lr=prof.memetic.lr * 0.4)
        adam_steps(ind, args.steps, steps, problem.clip, prof.memetic.reject_ratio, lambda _: None)
        best = ind.z if ind.best_z is None else ind.best_z
        rows.append({"plan": name.removeprefix("plan "), "own": start is z, "loss": score(best),
                     "input_iou": input_iou(problem, views, best, lod), "z": best})
    reference = trimesh.load(root / "results" / "synth" / case / "reference.ply", force="mesh")

    def world_iou(zz):
        mesh = problem.world_mesh(zz, 1)
        return silhouette_iou(reference, trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), 64, 128)["iou_mean"]

    mine = next(r for r in rows if r["own"])
    other = min((r for r in rows if not r["own"]), key=lambda r: r["loss"])
    print(f"{case}: fit {mine['plan']} loss {mine['loss']:.5f} (input view {mine['input_iou']:.3f}, world "
          f"{world_iou(mine['z']):.3f}); best other {other['plan']} {other['loss'] / mine['loss'] - 1:+.1%} (input "
          f"view {other['input_iou']:.3f}, world {world_iou(other['z']):.3f}); "
          + ", ".join(f"{r['plan']} {r['loss'] / mine['loss'] - 1:+.0%}" for r in rows if not r["own"]), flush=True)


if __name__ == "__main__":
    main()
