"""Moves of a camera of unknown pitch and lens (``ipm.photo``): pitch starts and the focal and pitch walks."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np

from ipm.photo import fov_of
from ipm.problem import Problem
from ipm.search.moves.base import Move, register
from ipm.settings import Range, Settings, at_least

FOV_DEG = Range(1.0, 170.0)
"""Fields of view the camera settings accept (horizontal degrees)."""


@dataclass(frozen=True)
class CameraSettings(Settings):
    """Settings of the unknown camera's moves."""

    KIND = "diff setting"
    focal_sweep: Annotated[int, at_least(0)] = 0
    """For an unknown field of view: before the last stage the focal gene is held at the estimate's and at this
    many points either side, the lowest loss wins (:func:`sweep_focal`); 0: none (docs/decisions.md, 'Focal sweep')."""
    focal_step: Annotated[float, Range(0.0, open_lo=True)] = 0.1
    """Grid step of ``focal_sweep`` in log focal length (0.1: about 10 % in focal length)."""
    focal_steps: Annotated[int, at_least(0)] = 100
    """Adam steps each point of ``focal_sweep`` gets, starting from its inner neighbour's result."""
    pitch_sweep: Annotated[int, at_least(0)] = 0
    """With ``focal_sweep``, after it: the camera's pitch held at the estimate's and this many points either side,
    ``pitch_step`` degrees apart, walked the same way; 0: none (docs/decisions.md, 'Pitch walk')."""
    pitch_step: Annotated[float, Range(0.0, open_lo=True)] = 0.25
    """Grid step of ``pitch_sweep`` in degrees."""
    pitch_starts: tuple[Annotated[float, Range(-90.0, 90.0)], ...] = ()
    """For an unknown camera with a given field of view: the memetic stage is run again per pitch here (degrees),
    held there, the finalists drawn from all runs; (): the usual stage alone (docs/decisions.md, 'Pitch starts')."""
    camera_start: Literal["prior", "learned"] = "learned"
    """Where an unknown camera's search starts: the pitch prior's middle, spread over the prior, with
    the given or default field of view (``prior``), or the camera-hidden regressor's proposed pitch
    and field of view (this one held unless given), its proposals first in the population and no
    pitch starts (``learned``; ``ipm.learned.propose.propose_camera``; docs/decisions.md,
    'Learned camera')."""
    fov_grid: tuple[Annotated[float, FOV_DEG], ...] = ()
    """For an unknown field of view: a fit per value here (horizontal degrees) as if it were given, the lowest loss
    kept (``ipm.methods.diff.fit_fov_grid``); (): estimated in one fit (docs/decisions.md, 'Field-of-view grid')."""


def _walk(trial, z: np.ndarray, i: int, step: float, points: int, label, steps: int, score) -> np.ndarray:
    """The gene ``i`` held at ``z``'s value and at ``points`` values on either side, ``step``
    apart, walking outwards with each point starting from its inner neighbour's result (a
    continuation: the rest follows the held gene a step at a time), everything else given
    ``steps`` Adam steps; the point of lowest ``score`` (the same render seeds for all) wins.
    ``label(value)`` names a point in the trace."""
    problem = trial.problem

    def held(start: np.ndarray, value: float) -> tuple[np.ndarray, float]:
        alt = start.copy()
        alt[i] = value

        def clip(x):
            x = problem.clip(x)
            x[i] = value
            return x

        return trial.tried(alt, label(value), steps, score, clip)

    centre = held(z, float(z[i]))
    tried = [centre]
    for direction in (-1, 1):
        point = centre
        for k in range(1, points + 1):
            value = float(z[i]) + direction * k * step
            if not problem.lower[i] <= value <= problem.upper[i]:
                break
            point = held(point[0], value)
            tried.append(point)
    return min(tried, key=lambda t: t[1])[0]


def sweep_focal(trial, z: np.ndarray, settings: CameraSettings) -> np.ndarray:
    """For an unknown camera whose field of view is not given: a profile of the loss over the
    focal length (:func:`_walk` over the focal gene, ``focal_sweep`` points either side,
    ``focal_step`` apart), then, with ``pitch_sweep``, over the pitch from the winner. The loss
    over the focal length is shallow (a few per cent between the truth's and a field of view 40 %
    too wide, cup_1), too shallow for Adam to cross with everything else moving; and a far focal
    length started from a point fitted to another scores worse than its own basin would, hence
    the walk. The pitch trades with the shape along a valley Adam crawls (dev building_d3 and d4
    stopped 0.25-0.35 degrees off with the true camera's basin 3-6 % lower in loss)."""
    problem = trial.problem
    camera = problem.camera
    score = trial.scorer((10_009, 10_010, 10_011, 10_012))
    z = _walk(trial, z, problem.camera_gene("log_focal"), settings.focal_step, settings.focal_sweep,
              lambda v: f"fov={np.degrees(fov_of(v, camera.fov0)):.1f}", settings.focal_steps, score)
    if settings.pitch_sweep > 0:
        z = _walk(trial, z, problem.camera_gene("pitch"), np.radians(settings.pitch_step), settings.pitch_sweep,
                  lambda v: f"pitch={np.degrees(v):.2f}", settings.focal_steps, score)
    return z


def sweeps_focal(problem: Problem, settings: CameraSettings) -> bool:
    """Whether :func:`sweep_focal` runs: a camera of unknown field of view and a sweep in the settings."""
    return problem.fov_estimated is True and settings.focal_sweep > 0 and settings.focal_steps > 0


@register
class FocalSweep(Move):
    """:func:`sweep_focal` before the last stage, its steps and scores at that stage's width."""

    name, phase, settings = "focal", "last", CameraSettings

    def applies(self, problem, profile) -> bool:
        return sweeps_focal(problem, profile.of(CameraSettings))

    def cost(self, problem, profile) -> int:
        s = profile.of(CameraSettings)
        return (2 * s.focal_sweep + 1 + 2 * s.pitch_sweep + (s.pitch_sweep > 0)) * s.focal_steps

    def __call__(self, cand, trial, settings):
        cand.z = sweep_focal(trial, cand.z, settings)
        return cand


@register
class PitchStarts(Move):
    """For an unknown camera with a given field of view (not a proposed one): a memetic run more per
    pitch start, held there."""

    name, phase, settings = "pitch starts", "memetic", CameraSettings

    def applies(self, problem, profile) -> bool:
        return problem.fov_estimated is False and not problem.camera.proposed and \
            bool(profile.of(CameraSettings).pitch_starts)

    def holds(self, problem, profile) -> list[dict[int, float]]:
        i = problem.camera_gene("pitch")
        return [{i: float(np.radians(p))} for p in profile.of(CameraSettings).pitch_starts]
