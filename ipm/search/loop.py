"""The differentiable path's one search loop: memetic search, then per stage the moves that apply and Adam.

Stages: the memetic stage at low resolution (its start pluggable, ``ipm.search.starts``), the
finalists' moves, then coarse-to-fine Adam with each stage's moves before it, the choice between
candidates after the first, and the moves of the end. The moves come from the generator and the
camera (``ipm.search.moves``); the loop knows none of them by name.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass, replace
from functools import partial
from typing import Annotated, Literal

import numpy as np
import pandas as pd

from ipm import lanes
from ipm.errors import UserError
from ipm.io.views import Views, resize_masks
from ipm.optim.memetic import Individual, adam_steps, memetic, step_evaluations
from ipm.problem import Problem
from ipm.runtime import thread_count
from ipm.search.moves import PHASES, moves_for
from ipm.search.objective import Objective, renderer_kind
from ipm.search.starts import preset_start
from ipm.search.trial import Candidate, Tracker, Trial, scorer
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class LoopSettings(Settings):
    """The loop's own settings: its stages and what it writes."""

    KIND = "diff setting"
    refine_res: tuple[Annotated[int, at_least(8)], ...] = (256, 512)
    """Render widths of the refinement stages (doubling)."""
    refine_iterations: tuple[Annotated[int, at_least(0)], ...] = (250, 250)
    """Adam steps per refinement stage (docs/decisions.md, 'Last stage length')."""
    refine_lod: Annotated[int, at_least(0)] = 1
    """Generator level of detail during refinement."""
    output_lod: Annotated[int, at_least(0)] = 1
    """Generator level of detail of the written mesh (level 2's 128-gon pole fans have 2.8-degree angles,
    which the malformed-triangle metric would count; docs/decisions.md, 'Output level of detail')."""
    refine_candidates: Annotated[int, at_least(1)] = 1
    """Finalists of the memetic stage (distinct topologies or yaws, :func:`finalists`) each taken through the
    finalist moves and the first refinement stage; the lowest loss goes on (docs/decisions.md, 'Finalists')."""
    start: Literal["presets", "learned"] = "learned"
    """The memetic stage's first population (``ipm.search.starts``): the learned regressor's
    proposals first (``learned_proposals`` of them) where it applies (a known camera and weights for
    the generator), else the generator's presets and random draws; ``presets`` always the latter
    (docs/decisions.md, 'Learned start')."""
    learned_proposals: Annotated[int, at_least(1)] = 4
    """How many of the regressor's proposals (its most probable discrete joints) the learned start puts
    in the population."""
    learned_generations: Annotated[int, at_least(1)] = 4
    """The memetic stage's generations (at most ``ga_iterations``) when it starts from the learned
    proposals, which start near the answer (docs/decisions.md, 'Memetic stage from the learned start')."""
    learned_fit: Annotated[float, at_least(0.0)] | None = None
    """The learned start checks its fit: where the best loss of its memetic stage is above this, the
    stage runs again from the presets' start at full length and both last generations go to the
    finalists; ``None`` trusts it always (docs/decisions.md, 'A learned start that checks its fit')."""
    plan_check: Annotated[float, Range(0.0, 1.0)] | None = None
    """The learned start checks its plan: where the input-view IoU (:func:`input_iou`) of its memetic
    stage's best is below this, a stage as long runs from the regressor's most probable joint for each
    other plan (``Generator.plan_parameters``) and its best basin joins the finalists as one more;
    ``None`` never (docs/decisions.md, 'A plan check by the input view')."""
    occam_plan: Annotated[float, Range(0.0, 1.0)] = 0.03
    """Between the refined finalists, one with fewer parts (``Generator.occam_parts``: a building's
    wings) is kept instead of the lowest loss where its loss is higher by at most this share of the
    object's pixels: more wings match one view's outline more easily than they are there
    (docs/decisions.md, 'A plan with fewer wings'); 0 keeps the lowest loss."""
    max_tilt: Annotated[float, Range(0.0, 0.5)] = 0.0
    """Bound of the two tilt angles (radians); 0 holds the object upright, the scene convention.
    Raise it for objects that may lean (docs/decisions.md, 'Upright objects')."""

    def __post_init__(self):
        super().__post_init__()
        if not self.refine_res or len(self.refine_res) != len(self.refine_iterations):
            raise UserError(f"refine_res and refine_iterations need one entry per stage each, got "
                            f"{list(self.refine_res)} and {list(self.refine_iterations)}")


def finalists(problem: Problem, final: list[Individual], k: int) -> list[Individual]:
    """Up to ``k`` of the memetic stage's last generation (best first) that differ from every one
    taken before in their topology or by more than a quarter turn in yaw: the basins worth a
    refinement of their own (the memetic resolution cannot tell a low gable roof from a hip)."""
    out = []
    for ind in final:
        yaw = ind.best_z[problem.n_shape]
        if all(problem.key(ind.best_z) != problem.key(o.best_z)
               or abs(np.angle(np.exp(1j * (yaw - o.best_z[problem.n_shape])))) > np.pi / 4 for o in out):
            out.append(ind)
        if len(out) == k:
            break
    return out


def occam_choice(losses: list[float], parts: list[int], margin: float) -> int:
    """Index of the finalist kept: the lowest loss, unless finalists with fewer parts lie within
    ``margin`` of it; then, of those, the fewest parts and the lowest loss."""
    k = int(np.argmin(losses))
    fewer = [i for i, (loss, n) in enumerate(zip(losses, parts)) if n < parts[k] and loss - losses[k] <= margin]
    return min(fewer, key=lambda i: (parts[i], losses[i])) if fewer else k


def twin_choice(losses: list[float], credits: list[float], lineage: list[int]) -> list[int]:
    """Indices of the candidates left once twins (those of one ``lineage``) are compared: of each
    lineage the lowest loss less its credit (evidence the loss does not weigh), in their order."""
    best = {}
    for i, (loss, credit, line) in enumerate(zip(losses, credits, lineage)):
        if line not in best or loss - credit < losses[best[line]] - credits[best[line]]:
            best[line] = i
    return sorted(best.values())


def input_iou(problem: Problem, views: Views, z: np.ndarray, lod: int, res: int = 128) -> float:
    """Mean IoU of the input masks and the silhouettes of ``z``'s mesh from the input cameras (open3d
    ray casting at ``res`` px): the trace's progress in the metric's own terms. NaN where the
    cameras are not known (a photo), the images are not square or open3d is not installed (the GPU
    machine: the value only annotates the trace, so the fit itself runs without it)."""
    if (views.camera is not None or views.width != views.height or views.masks is None
            or importlib.util.find_spec("open3d") is None):
        return float("nan")
    import trimesh

    from ipm.metrics.silhouette import raycast_masks, view_ious

    mesh, res = problem.world_mesh(z, lod), min(res, views.width)
    rec = raycast_masks(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), list(views.c2w), res,
                        float(np.degrees(views.fov_x)))
    return float(view_ious(resize_masks(views.masks, res) > 0.5, rec).mean())


def planned_evaluations(problem: Problem, profile, mem, phase: dict, runs: int) -> int:
    """The evaluations a fit plans (its progress bar's total): ``runs`` memetic stages of ``mem``,
    each move's cost (``Move.cost``) on the candidates its phase sees, the refinement stages'
    steps; forks and stages the search adds as it goes extend it then."""
    loop = profile.loop

    def cost(name: str) -> int:
        return sum(m.cost(problem, profile) for m in phase[name])

    seen = [loop.refine_candidates] + [1] * (len(loop.refine_res) - 1)  # candidates in each refinement stage
    return (runs * mem.ga_iterations * (mem.adam_per_iteration + mem.population)
            + loop.refine_candidates * cost("finalist")
            + sum(k * (cost("stage") + cost("refine") + steps + 1) for k, steps in zip(seen, loop.refine_iterations))
            + seen[-1] * cost("last") + cost("end"))


def reconstruct(problem: Problem, views: Views, profile, seed: int = 0, progress: bool = True,
                start=preset_start) -> tuple[np.ndarray, pd.DataFrame]:
    """Best ``z`` for ``views`` under ``profile`` (``ipm.profiles.DiffProfile``) and the trace (one row
    per evaluation; at the end of each stage its ``iou`` column holds the input-view IoU of the
    stage's best, :func:`input_iou`). ``start`` makes the memetic stage's first population. With
    the JAX renderer, independent tries run side by side on the process's threads (``ipm.lanes``:
    the same result and trace as one after another)."""
    jax_renderer = renderer_kind(profile.objective.renderer, problem.fov_estimated is True) == "jax"
    side = lanes.Lanes(thread_count() if jax_renderer else 1)
    try:
        return _search(problem, views, profile, seed, progress, start, side)
    finally:
        side.close()


def _search(problem: Problem, views: Views, profile, seed: int, progress: bool, start, side: lanes.Lanes):
    """:func:`reconstruct`, its tries run by ``side``."""
    loop, full = profile.loop, profile.memetic
    learned = getattr(start, "learned", False)
    mem = replace(full, ga_iterations=min(full.ga_iterations, loop.learned_generations)) if learned else full
    moves = [m for m in moves_for(problem) if m.applies(problem, profile)]
    phase = {p: [m for m in moves if m.phase == p] for p in PHASES}
    holds = [{}] + [h for m in phase["memetic"] for h in m.holds(problem, profile)]
    total = planned_evaluations(problem, profile, mem, phase, len(holds))
    track, rng, least = Tracker(total, progress), np.random.default_rng(seed), problem.generator.min_fit_lod
    ious, cast = {}, {}

    def iou_of(z: np.ndarray) -> float:
        """:func:`input_iou` of ``z`` at the refinement's level of detail, each ``z`` cast once."""
        key = np.asarray(z).tobytes()
        if key not in cast:
            cast[key] = input_iou(problem, views, z, max(loop.refine_lod, least))
        return cast[key]

    def checkpoint(z: np.ndarray) -> None:
        """The input-view IoU of the current stage's best, on the stage's last trace row."""
        ious[len(track.rows) - 1] = iou_of(z)

    def run(move, cands: list[Candidate], steps, score) -> list[Candidate]:
        label = move.label or move.name
        lanes.later(track.enter, label, steps.width)  # in order, where candidates run side by side
        trial = Trial(problem, steps, score, mem.lr, mem.reject_ratio, views, profile, track.on_eval,
                      track.recorder(label, score.width), track.extend, side)
        out = []
        for c in cands:
            steps.rewind()  # each candidate's steps draw the same seeds, whatever ran before
            moved = move(c, trial, profile.of(move.settings) if move.settings else None)
            if isinstance(moved, list):  # a fork: each twin refined through the first stage
                track.extend((len(moved) - 1) * (loop.refine_iterations[0] + 1))
                out += moved
            else:
                out.append(moved)
        return out

    objective = Objective(problem, views, mem.memetic_res, max(mem.memetic_lod, least), profile.objective)

    def stage(pop: list[Individual], settings) -> list[Individual]:
        track.enter("memetic", objective.width)
        return memetic(pop, objective, problem.clip, problem.key, problem.n_shape, problem.spec.levels, settings,
                       rng, track.on_eval, prepare=objective.match_area, yaw_free=problem.yaw_free, side=side)

    final, added, elsewhere = [], set(), []
    for held in holds:
        with problem.holding(held):
            last = stage(start(problem, mem, rng, objective.match_area), mem)
            if learned:
                again = loop.learned_fit is not None and last[0].best_loss > loop.learned_fit
                track.recorder("start", objective.width)("learned: presets added" if again else "learned: kept",
                                                         last[0].best_loss)
                if again:
                    track.extend(full.ga_iterations * (full.adam_per_iteration + full.population))
                    more = stage(preset_start(problem, full, rng, objective.match_area), full)
                    added |= {id(ind) for ind in more}
                    last += more
                if loop.plan_check is not None and problem.generator.plan_parameters:
                    seen = iou_of(last[0].best_z)
                    other = bool(seen < loop.plan_check)
                    track.recorder("start", objective.width)(
                        f"plan check: input IoU {seen:.4f}, " + ("other plans added" if other else "plan kept"),
                        last[0].best_loss)
                    if other:
                        per_finalist = sum(m.cost(problem, profile)
                                           for p in ("finalist", "stage", "refine") for m in phase[p])
                        track.extend(mem.ga_iterations * (mem.adam_per_iteration + mem.population)
                                     + loop.refine_iterations[0] + 1 + per_finalist)
                        others = start.elsewhere(problem, mem, rng, objective.match_area, last[0].best_z)
                        elsewhere += stage(others, mem)
            final += last
    final.sort(key=lambda ind: ind.best_loss)
    if added:
        track.recorder("start", objective.width)(
            "won: presets" if id(final[0]) in added else "won: learned", final[0].best_loss)
    checkpoint(final[0].best_z)
    chosen = finalists(problem, final, loop.refine_candidates)
    extra = None
    if elsewhere:  # the other plans' best basin one finalist more; the learned stage's finalists all stay
        more = finalists(problem, chosen + sorted(elsewhere, key=lambda ind: ind.best_loss), len(chosen) + 1)
        extra, chosen = (len(chosen) if len(more) > len(chosen) else None), more
    cands = [Candidate(ind.best_z, lineage=i) for i, ind in enumerate(chosen)]
    for move in phase["finalist"]:
        cands = run(move, cands, objective, objective)
    checkpoint(cands[0].z)
    for stage, (res, iters) in enumerate(zip(loop.refine_res, loop.refine_iterations)):
        previous, objective = objective, Objective(problem, views, res, max(loop.refine_lod, least), profile.objective)
        for move in phase["stage"] + (phase["last"] if stage == len(loop.refine_res) - 1 else []):
            cands = run(move, cands, previous if move.steps_before else objective, objective)

        def refine(cand: Candidate, objective=objective, iters=iters, res=res) -> Candidate:
            for move in phase["refine"]:
                cand = run(move, [cand], objective, objective)[0]
            lanes.later(track.enter, "refine", res, True)
            objective.rewind()
            ind = Individual(cand.z, problem.key(cand.z), "refine", lr=mem.lr * 0.4)
            adam_steps(ind, iters + 1, objective, problem.clip, mem.reject_ratio, track.on_eval)
            return replace(cand, z=ind.best_z, settled=frozenset())

        # each candidate's steps draw the same seeds: the refinements run side by side
        draws = {objective: step_evaluations(iters + 1, True)}
        cands = side.map([lanes.Task(partial(refine, cand), draws, (objective,)) for cand in cands])
        if len(cands) > 1:
            score, record = scorer(objective, (10_007, 10_008)), track.recorder("choose", res)
            losses = [score(c.z) for c in cands]
            for i, (loss, c) in enumerate(zip(losses, cands)):
                record(f"finalist {i}" + (f", twin credited {c.credit:.5f}" if c.credit else "")
                       + (", unturned twin" if c.keep_facing else ""), loss)
            left = twin_choice(losses, [c.credit for c in cands], [c.lineage for c in cands])
            for i in sorted(set(range(len(cands))) - set(left)):
                record(f"finalist {i} left: its twin's loss less its credit is lower", losses[i])
            cands, losses = [cands[i] for i in left], [losses[i] for i in left]
            parts = [problem.generator.occam_parts(problem.spec.from_unit(c.z[: problem.n_shape])) for c in cands]
            k, lowest = occam_choice(losses, parts, loop.occam_plan * objective.object_share), int(np.argmin(losses))
            if k != lowest:
                record(f"finalist {left[k]} kept: {parts[k]} parts, the lowest loss's {parts[lowest]}", losses[k])
            cands = [cands[k]]
        checkpoint(cands[0].z)
    if extra is not None:
        track.recorder("start", objective.width)(
            "plan finalist: " + ("the other plans' kept" if cands[0].lineage == extra else "the learned stage's kept"),
            track.rows[-1][5])
    for move in phase["end"]:
        cands = run(move, cands, objective, objective)
    checkpoint(cands[0].z)
    trace = track.frame()
    trace["iou"] = pd.Series(ious, dtype=float)
    return cands[0].z, trace
