"""The plan move: the other plans laid over the fit's extent, one kept only past a margin.

A generator that lists this move has ``plan_variants(x)``: (name, parameters, object-frame move)
for every other plan laid over the extent ``x`` covers (buildings: ``ipm.generators.buildings.plans``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.problem import POSE_NAMES
from ipm.search.moves.base import Move, register
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class PlanSettings(Settings):
    """Settings of :func:`relay_plan`."""

    KIND = "diff setting"
    plan_steps: Annotated[int, at_least(0)] = 0
    """Adam steps the fit and each other plan laid over its extent get before the roof race; 0: none
    (docs/decisions.md, 'A plan laid over the fit, kept past a margin')."""
    plan_margin: Annotated[float, Range(0.0, 1.0)] = 0.12
    """A laid plan replaces the fit only with a loss lower by more than this fraction; else the fit
    goes on untouched (docs/decisions.md, 'A plan laid over the fit, kept past a margin')."""


def laid_starts(problem, z: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """``z`` with each of its generator's ``plan_variants``: the shape set to the plan's parameters,
    the object moved so that the plan's extent lies where ``z``'s did."""
    n, t = problem.n_shape, problem.n_shape + POSE_NAMES.index("dx")
    out = []
    for name, x, move in problem.generator.plan_variants(problem.spec.from_unit(z[:n])):
        start = problem.with_shape(z, x)
        ends = problem.to_world(start)(np.stack([np.zeros(3), move]))
        start[t:t + 3] += (ends[1] - ends[0]) / problem.anchor_s
        out.append((f"plan {name}", problem.clip(start)))
    return out


def relay_plan(trial, z: np.ndarray, settings: PlanSettings) -> np.ndarray:
    """``z`` and every other plan laid over its extent, each given ``plan_steps`` Adam steps and
    compared under the trial's score (same render seeds): the lowest laid plan wins only with a
    loss lower than ``z``'s by more than ``plan_margin``; else ``z`` as it was. From one view a fit
    keeps the plan its memetic stage found, and the roof kinds and wings bend to cover what a
    wrong plan leaves out; a plan that covers the outline with a clearly lower loss is a basin the
    fit would not reach, and near-ties are left alone (more wings match one outline more easily
    than they are there)."""
    return trial.race(z, "plan as fitted", laid_starts(trial.problem, z), settings.plan_steps, settings.plan_margin,
                      trial.scorer((10_007, 10_008)), untouched=True)


@register
class PlanMove(Move):
    """:func:`relay_plan` before the last stage: steps at the previous stage's width, scores at this one's."""

    name, phase, settings, steps_before = "plan", "last", PlanSettings, True

    def applies(self, problem, profile) -> bool:
        return profile.of(PlanSettings).plan_steps > 0

    def cost(self, problem, profile) -> int:
        others = len(problem.generator.plan_variants(problem.spec.default))
        return (others + 1) * profile.of(PlanSettings).plan_steps

    def __call__(self, cand, trial, settings):
        cand.z = relay_plan(trial, cand.z, settings)
        return cand
