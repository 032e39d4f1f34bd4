"""The placement sweep: a small part (a chimney) tried at each of the generator's places for it.

A generator that lists this move has ``placements``: starting values for the part, each a
complete place for it (buildings: the chimney, switched on, mid-sized, at nine places on the roof).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.search.moves.base import Move, register
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class PlaceSettings(Settings):
    """Settings of :func:`sweep_place`."""

    KIND = "diff setting"
    place_steps: Annotated[int, at_least(0)] = 0
    """Adam steps of each start of the sweep (the fit as it stands and its small part at each of the
    generator's ``placements``), after the line-of-sight sweep; 0: none (docs/decisions.md, 'Chimney sweep')."""
    place_margin: Annotated[float, Range(0.0, 1.0)] = 0.4
    """A placement replaces the part as it stands only with a loss lower by more than this fraction
    (docs/decisions.md, 'Chimney sweep')."""


def sweep_place(trial, z: np.ndarray, settings: PlaceSettings) -> np.ndarray:
    """``z`` and ``z`` with each of the generator's placements, each given ``place_steps`` Adam steps
    and compared under the trial's score (same render seeds); the lowest loss wins if it is lower
    than ``z``'s by more than ``place_margin``. Such a part covers a few hundred pixels, and where
    it is not drawn its edges give no gradient, so a fit keeps it wherever the memetic stage left
    it (or leaves it out)."""
    problem = trial.problem
    spec, n = problem.spec, problem.n_shape
    x = spec.from_unit(z[:n])
    starts = []
    for values in problem.generator.placements:
        alt_x = x.copy()
        alt_x[[spec.index[k] for k in values]] = list(values.values())
        starts.append(("place " + " ".join(f"{k}={v:g}" for k, v in values.items()), problem.with_shape(z, alt_x)))
    return trial.race(z, "place kept", starts, settings.place_steps, settings.place_margin,
                      trial.scorer((10_015, 10_016)))


@register
class PlaceSweep(Move):
    """:func:`sweep_place` before the last stage: steps at the previous stage's width, scores at this one's."""

    name, phase, settings, steps_before = "place", "last", PlaceSettings, True

    def applies(self, problem, profile) -> bool:
        return bool(problem.generator.placements) and profile.of(PlaceSettings).place_steps > 0

    def cost(self, problem, profile) -> int:
        return (len(problem.generator.placements) + 1) * profile.of(PlaceSettings).place_steps

    def __call__(self, cand, trial, settings):
        cand.z = sweep_place(trial, cand.z, settings)
        return cand
