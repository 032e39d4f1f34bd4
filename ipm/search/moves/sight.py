"""The line-of-sight sweep: the footprint side the first view looks along, tried stretched and shrunk.

A generator that lists this move has a ``footprint``: the names of the parameters that set its
extent along its own x and z axes, each independent of the other (buildings: width and depth).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.io.views import Views
from ipm.problem import POSE_NAMES, Problem
from ipm.search.moves.base import Move, register
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class SightSettings(Settings):
    """Settings of :func:`sweep_sight`."""

    KIND = "diff setting"
    sight_steps: Annotated[int, at_least(0)] = 0
    """Adam steps of each start of the sweep (the footprint side the first view looks along tried at each of
    ``sight_factors``, near face held); 0: none (docs/decisions.md, 'Line-of-sight sweep')."""
    sight_factors: tuple[Annotated[float, Range(0.0, open_lo=True)], ...] = (0.7, 0.84, 1.19, 1.43)
    """The stretches ``sight_steps`` tries (about 18 % apart in the log)."""
    sight_margin: Annotated[float, Range(0.0, 1.0)] = 0.05
    """A stretch replaces the extent as it stands only with a loss lower by more than this fraction
    (docs/decisions.md, 'Line-of-sight sweep')."""


def sight_axis(problem: Problem, views: Views, z: np.ndarray) -> tuple[int, np.ndarray]:
    """The ``footprint`` parameter (its index) whose side the first view looks along more nearly
    at ``z``'s pose, and the world step that moves the object by one unit of that parameter away
    from the camera."""
    world = problem.to_world(z)
    origin, ends = world(np.zeros((1, 3)))[0], world(np.eye(3)[[0, 2]])
    axes = ends - origin  # the object's x and z axes in the world, times its scale
    along = axes @ (views.c2w[0, :3, 3] - origin)
    k = int(np.argmax(np.abs(along)))
    return problem.spec.index[problem.generator.footprint[k]], -np.sign(along[k]) * axes[k]


def sweep_sight(trial, z: np.ndarray, settings: SightSettings) -> np.ndarray:
    """The extent along the first view's line of sight tried at several values: ``z`` and ``z``
    with that footprint side times each of ``sight_factors`` (the face nearest the camera held in
    place, so the front stays where the image puts it), each given ``sight_steps`` Adam steps and
    compared under the trial's score (same render seeds); the lowest loss wins if it is lower than
    the unstretched one's by more than ``sight_margin`` (a fraction). From one view that extent
    shows only in a sliver of side wall and in the roof's rise, which trade with the pose, so a fit
    keeps whatever extent it started from."""
    problem = trial.problem
    (i, away), spec, n = sight_axis(problem, trial.views, z), problem.spec, problem.n_shape
    t = n + POSE_NAMES.index("dx")  # the translation genes dx, dy, dz
    x = spec.from_unit(z[:n])
    starts = []
    for factor in settings.sight_factors:
        alt_x = x.copy()
        alt_x[i] *= factor
        alt_x = spec.clip(alt_x)
        alt = problem.with_shape(z, alt_x)
        alt[t:t + 3] += away * (alt_x[i] - x[i]) / 2 / problem.anchor_s
        starts.append((f"sight x{factor:g}", problem.clip(alt)))
    return trial.race(z, "sight x1", starts, settings.sight_steps, settings.sight_margin,
                      trial.scorer((10_007, 10_008)))


@register
class SightSweep(Move):
    """:func:`sweep_sight` before the last stage: steps at the previous stage's width, scores at this one's."""

    name, phase, settings, steps_before = "sight", "last", SightSettings, True

    def applies(self, problem, profile) -> bool:
        return problem.generator.footprint is not None and profile.of(SightSettings).sight_steps > 0

    def cost(self, problem, profile) -> int:
        settings = profile.of(SightSettings)
        return (len(settings.sight_factors) + 1) * settings.sight_steps

    def __call__(self, cand, trial, settings):
        cand.z = sweep_sight(trial, cand.z, settings)
        return cand
