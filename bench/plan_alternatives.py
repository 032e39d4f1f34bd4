"""Benchmark: the other plans of a finished building fit laid over its footprint, refined and scored
(the measurement behind docs/results.md, "The plans laid over a fit's footprint").

For a workflow run's fit (``ROOT/results/reconstruct/diff_1v/CASE/s0``) every other plan
(rectangle, L, T, U, each with and without the annex) is laid over the extent the fit covers
(:func:`laid`); each, and the fit itself, gets ``--steps`` Adam steps at 128 px, and all are scored
at 256 px over two fixed render seeds, with the input view's IoU and the 64-view world IoU (128 px)
of the fit and of the best alternative. ``--truth``: the case's own parameters and pose (an
in-family case's ``ground_truth.json``) get the same steps and scores, which tells a loss the
search never reached from one the view does not show. Prints one line a case.

    .venv/bin/python bench/plan_alternatives.py ROOT CASE [--seed 0] [--steps 90] [--truth]

One case a process: every plan compiles programs of its own, and a process that fits many
buildings' plans runs out of the compiler's code memory.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ipm.generators.buildings.table import L_PLAN, RECTANGLE, T_PLAN, U_PLAN, WINGS

SHARE_MAIN = 0.6
"""The main wing's share of the extent's depth where the plan has back wings (the rest theirs)."""
SHARE_ANNEX = 0.25
"""The annex's share of the extent's width."""
ANNEX_DEPTH = 0.6
"""The annex's width across it as a share of the main wing's depth."""
BACK_WIDTH = {RECTANGLE: 0.45, L_PLAN: 0.45, T_PLAN: 0.45, U_PLAN: 0.3}
"""A back wing's width as a share of the main wing's, by plan (each of a U's two; a rectangle's unused)."""
WING_PITCH = 0.8
"""A laid wing's roof height as a share of the main roof's (a wing is narrower than the main wing)."""


def extent(p: dict) -> tuple[float, float, float, float]:
    """The object-frame footprint (x0, x1, z0, z1) of a buildings parameter set: the main wing,
    the back wings its plan has (towards -z) and the annex (towards +x), as the generator lays them
    (``ipm.generators.buildings.footprint.wing_frame``)."""
    hx, hz = p["width"] / 2, p["depth"] / 2
    plan, annex = int(round(p["template"])), int(round(p["annex"]))
    back = max([p["wing1_length"]] * (plan >= L_PLAN) + [p["wing2_length"]] * (plan == U_PLAN) + [0.0])
    return -hx, hx + (p["wing3_length"] if annex else 0.0), -hz - back, hz


def laid(p: dict, plan: int, annex: int) -> tuple[dict, np.ndarray]:
    """``p`` with plan ``plan`` and annex ``annex`` laid over its extent (the shares above; every
    wing at the main wing's storeys and roof kind), and the object-frame move (3,) that puts the
    new extent where the old one was (before the generator's bounds clip it)."""
    x0, x1, z0, z1 = extent(p)
    width, depth = x1 - x0, z1 - z0
    q = dict(p, template=plan, annex=annex)
    q["width"] = (1 - SHARE_ANNEX) * width if annex else width
    q["depth"] = SHARE_MAIN * depth if plan != RECTANGLE else depth
    for k in (1, 2):
        q[f"wing{k}_length"] = (1 - SHARE_MAIN) * depth
        q[f"wing{k}_width"] = BACK_WIDTH[plan] * q["width"]
        q[f"wing{k}_shift"] = 0.0
    q["wing3_length"], q["wing3_width"], q["wing3_shift"] = SHARE_ANNEX * width, ANNEX_DEPTH * q["depth"], 0.0
    for k in WINGS:
        q[f"wing{k}_floors"], q[f"wing{k}_roof"] = p["floors"], p["roof_type"]
        q[f"wing{k}_roof_height"] = WING_PITCH * p["roof_height"]
    n0, n1, m0, m1 = extent(q)
    return q, np.array([(x0 + x1 - n0 - n1) / 2, 0.0, (z0 + z1 - m0 - m1) / 2])


def truth_fit(case_root: Path) -> dict:
    """A synthesised in-family case's ground truth (``ground_truth.json``) as a params.json's
    ``params`` and ``pose`` (upright, as the synthesis places it)."""
    truth = json.loads((case_root / "ground_truth.json").read_text())
    if "params" not in truth.get("source", {}):
        raise SystemExit(f"{case_root.name} has no generator parameters: --truth needs an in-family case")
    pose = truth["pose"]
    return {"params": truth["source"]["params"], "pose": {"yaw": float(np.radians(pose["yaw_deg"])), "tilt_x": 0.0,
            "tilt_z": 0.0, "translation": pose["translation"], "scale": pose["scale"]}}


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
    ap.add_argument("--truth", action="store_true", help="also the case's own parameters and pose")
    args = ap.parse_args()
    import trimesh

    from ipm.generators import get_generator
    from ipm.generators.buildings.table import PLANS
    from ipm.io.views import load_views
    from ipm.metrics.silhouette import silhouette_iou
    from ipm.optim.memetic import Individual, adam_steps
    from ipm.problem import Problem
    from ipm.profiles import get_profile
    from ipm.search.loop import input_iou
    from ipm.search.objective import Objective
    from ipm.search.trial import scorer

    root, case, prof = Path(args.root), args.case, get_profile("default")
    gen = get_generator("buildings")
    views = load_views(root / "results" / "synth" / case / "hemi1" / "transforms.json")
    problem = Problem.for_views(gen, views, max_tilt=prof.loop.max_tilt)
    fit = json.loads((root / "results" / "reconstruct" / "diff_1v" / case / f"s{args.seed}" / "params.json").read_text())
    z, spec, n = fitted_z(problem, fit), gen.spec, problem.n_shape
    lod = max(prof.loop.refine_lod, gen.min_fit_lod)
    steps, score = Objective(problem, views, 128, lod, prof.objective), scorer(
        Objective(problem, views, 256, lod, prof.objective), (10_005, 10_006))
    own = (int(round(fit["params"]["template"])), int(round(fit["params"]["annex"])))
    truth = truth_fit(root / "results" / "synth" / case) if args.truth else None  # read before the fits

    def settled(start: np.ndarray, plan: str, is_own: bool) -> dict:
        """``start`` after the Adam steps, with its loss and input-view IoU."""
        ind = Individual(start, problem.key(start), "plan", lr=prof.memetic.lr * 0.4)
        adam_steps(ind, args.steps, steps, problem.clip, prof.memetic.reject_ratio, lambda _: None)
        best = ind.z if ind.best_z is None else ind.best_z
        return {"plan": plan, "own": is_own, "loss": score(best), "input_iou": input_iou(problem, views, best, lod),
                "z": best}

    rows = []
    for plan in range(len(PLANS)):
        for annex in (0, 1):
            start = z.copy()
            if (plan, annex) != own:
                q, move = laid(fit["params"], plan, annex)
                start[:n] = spec.to_unit(spec.clip(spec.from_dict(q)))
                ends = problem.to_world(start)(np.stack([np.zeros(3), move]))
                start[n + 3:n + 6] += (ends[1] - ends[0]) / problem.anchor_s
                start = problem.clip(start)
            rows.append(settled(start, PLANS[plan] + (" + annex" if annex else ""), (plan, annex) == own))
    truths = [] if truth is None else [settled(problem.clip(fitted_z(problem, truth)), "truth", False)]
    reference = trimesh.load(root / "results" / "synth" / case / "reference.ply", force="mesh")

    def world_iou(zz):
        mesh = problem.world_mesh(zz, 1)
        return silhouette_iou(reference, trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), 64, 128)["iou_mean"]

    mine = next(r for r in rows if r["own"])
    other = min((r for r in rows if not r["own"]), key=lambda r: r["loss"])
    said = "".join(f"; truth {r['loss'] / mine['loss'] - 1:+.1%} (input view {r['input_iou']:.3f}, world "
                   f"{world_iou(r['z']):.3f})" for r in truths)
    print(f"{case}: fit {mine['plan']} loss {mine['loss']:.5f} (input view {mine['input_iou']:.3f}, world "
          f"{world_iou(mine['z']):.3f}); best other {other['plan']} {other['loss'] / mine['loss'] - 1:+.1%} (input "
          f"view {other['input_iou']:.3f}, world {world_iou(other['z']):.3f}); "
          + ", ".join(f"{r['plan']} {r['loss'] / mine['loss'] - 1:+.0%}" for r in rows if not r["own"]) + said,
          flush=True)


if __name__ == "__main__":
    main()
