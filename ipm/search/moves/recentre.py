"""Re-centring: the lengths traded against the pose scale before each refinement stage (the same mesh)."""
from __future__ import annotations

from dataclasses import dataclass

from ipm.search.moves.base import Move, register
from ipm.settings import Settings


@dataclass(frozen=True)
class RecentreSettings(Settings):
    """Settings of the re-centring move."""

    KIND = "diff setting"
    recentre: bool = True
    """Before each refinement stage, trade the lengths against the pose scale (the same mesh,
    :meth:`ipm.problem.Problem.recentred`) so they sit midway between their bounds
    (docs/decisions.md, 'Re-centring')."""


@register
class Recentre(Move):
    """:meth:`ipm.problem.Problem.recentred` on every candidate before each stage (a generator with
    the gauge: ``Generator.ratios``)."""

    name, phase, settings = "recentre", "stage", RecentreSettings

    def applies(self, problem, profile) -> bool:
        return profile.of(RecentreSettings).recentre

    def __call__(self, cand, trial, settings):
        cand.z = trial.problem.recentred(cand.z)
        return cand
