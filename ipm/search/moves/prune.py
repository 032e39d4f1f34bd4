"""The prune race: the fit against itself with fewer parts (a building's wings left out).

A generator that lists this move implements ``pruned(x)``: ``x`` with fewer parts, each version
named (buildings: every set of its wings with one or more left out).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.search.moves.base import Move, register
from ipm.search.trial import survivors
from ipm.settings import Settings, at_least


@dataclass(frozen=True)
class PruneSettings(Settings):
    """Settings of :func:`race_pruned`."""

    KIND = "diff setting"
    prune_steps: Annotated[int, at_least(0)] = 0
    """Adam steps each version gets per round of the race before the roof race; 0: none
    (docs/decisions.md, 'Prune race')."""
    prune_rounds: Annotated[int, at_least(1)] = 3
    """Rounds of the race: after each, the better half (at least two) get ``prune_steps`` more."""


def race_pruned(trial, z: np.ndarray, settings: PruneSettings) -> np.ndarray:
    """``z`` and each version of it with fewer parts (``generator.pruned``) raced over
    ``prune_rounds`` of ``prune_steps`` Adam steps under the trial's score (same render seeds):
    the lowest wins. A memetic stage that has put a wing where the view shows none keeps it, its
    size shrunk where it does least harm, since leaving it out is a jump no step makes. Where the
    fit as it stands wins, ``z`` itself comes back (its steps discarded): a race that changes
    nothing leaves the rest of the fit as it was."""
    problem = trial.problem
    spec, n = problem.spec, problem.n_shape
    pool = [("as it stands", z)] + [(name, problem.with_shape(z, x))
                                     for name, x in problem.generator.pruned(spec.from_unit(z[:n]))]
    if len(pool) == 1:
        return z
    best = trial.rounds(pool, settings.prune_steps, settings.prune_rounds, trial.scorer((10_009, 10_010)))[0]
    return z if best[0] == "as it stands" else best[1]


def race_evaluations(starts: int, settings: PruneSettings) -> int:
    """Adam steps :func:`race_pruned` spends on ``starts`` versions (the progress bar's share)."""
    total = 0
    for _ in range(settings.prune_rounds):
        total += starts * settings.prune_steps
        starts = survivors(starts)
    return total


@register
class PruneRace(Move):
    """:func:`race_pruned` before the last stage: steps at the previous stage's width, scores at this one's."""

    name, phase, settings, steps_before = "prune", "last", PruneSettings, True

    def applies(self, problem, profile) -> bool:
        return profile.of(PruneSettings).prune_steps > 0 and hasattr(problem.generator, "pruned")

    def cost(self, problem, profile) -> int:
        return race_evaluations(2, profile.of(PruneSettings))  # a fit of one wing: itself and the rectangle

    def __call__(self, cand, trial, settings):
        cand.z = race_pruned(trial, cand.z, settings)
        return cand
