"""Counts read off the class masks: storeys and windows per facade set to what the input views show.

A generator that lists this move has facades (``ipm.facades``): ``counts``, ``facing``,
``facades``, ``marker``, ``marker_extent``, ``change_count`` and ``quarter_turned``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ipm.facades import marker_reading, read_counts
from ipm.io.views import Views
from ipm.problem import Problem
from ipm.search.moves.base import Move, register
from ipm.search.objective import ObjectiveSettings, class_masks
from ipm.settings import Settings


@dataclass(frozen=True)
class CountsSettings(Settings):
    """Settings of the count reading."""

    KIND = "diff setting"
    read_counts: bool = True
    """Before polish and before each refinement stage, set the counts (storeys, windows per facade) to
    those the input views' class masks show on the facades they face (``ipm.facades``); needs class
    masks (buildings' window masks) and a ``window_weight`` above 0, else nothing happens."""


def reads(profile) -> bool:
    """Whether the counts are read under ``profile``: on, and the class-mask term weighed."""
    return profile.of(CountsSettings).read_counts and profile.of(ObjectiveSettings).window_weight > 0


def turned(problem: Problem, z: np.ndarray, angle: float) -> np.ndarray:
    """``z`` turned by ``angle`` about +y; a quarter turn also trades the footprint's sides
    (``quarter_turned``), so that the turned object covers the same ground."""
    n = problem.n_shape
    if abs(np.cos(angle)) < 0.5:
        z = problem.with_shape(z, problem.generator.quarter_turned(problem.spec.from_unit(z[:n])))
    return problem.turned(z, angle)


def read_counts_into(problem: Problem, views: Views, z: np.ndarray,
                     angle: float | None = None) -> tuple[np.ndarray, list[str], frozenset[str]]:
    """``z`` turned by ``angle`` (default: as the views' marker class says it should turn,
    :func:`turn_asked`), then with the counts the input views' class masks show set to what they
    show (:func:`ipm.facades.read_counts` on the facades the views face; a storey more or less
    keeps the walls' height: ``change_count``); the changes made; and the counts the views
    settle, for polish to leave: those read (the next reading would set them again) and those of
    sides no view faces (no loss tells their values apart). ``z`` itself, no change and nothing
    settled when the views have no class masks or the generator no counts."""
    gen = problem.generator
    masks = class_masks(gen, views)
    if masks is None or not gen.counts:
        return z, [], frozenset()
    angle = turn_asked(problem, views, z)[0] if angle is None else angle
    if angle:
        return _counts_read(problem, views, masks[0], turned(problem, z, angle), [f"yaw{np.degrees(angle):+.0f}"])
    return _counts_read(problem, views, masks[0], z, [])


def turn_asked(problem: Problem, views: Views, z: np.ndarray) -> tuple[float, float]:
    """The turn the views' marker class asks of ``z`` (:func:`ipm.facades.marker_reading`: a door
    on the back or a side) and its evidence, the share of the views' pixels the marker covers;
    (0, 0) where the views have no class masks or the generator no counts or marker."""
    gen, spec, n = problem.generator, problem.spec, problem.n_shape
    marker = class_masks(gen, views, gen.marker[0]) if gen.marker and gen.counts else None
    if marker is None:
        return 0.0, 0.0
    return marker_reading(gen, spec.from_unit(z[:n]), problem.to_world(z), views, marker[0])


def _counts_read(problem: Problem, views: Views, masks: np.ndarray, z: np.ndarray,
                 changes: list[str]) -> tuple[np.ndarray, list[str], frozenset[str]]:
    """``z`` with the counts the class ``masks`` show set (:func:`read_counts_into`), ``changes`` with
    those made, and the counts settled."""
    gen, spec, n = problem.generator, problem.spec, problem.n_shape
    x = spec.from_unit(z[:n])
    pose = problem.decode(z)["pose"]
    seen = gen.seen_counts(pose["yaw"], views.c2w[:, :3, 3] - np.asarray(pose["translation"]))
    found = read_counts(gen, x, problem.to_world(z), seen, views, masks, views.masks)
    changes = list(changes)
    for name, value in found.items():
        if value != round(x[spec.index[name]]):
            x = gen.change_count(x, name, value)
            changes.append(f"{name}={value}")
    return problem.with_shape(z, x), changes, frozenset(found) | (frozenset(gen.counts) - frozenset(seen))


class _Read(Move):
    settings = CountsSettings
    fork = False
    """Whether a turn the marker asks for forks the candidate: the turned point, credited with the
    marker's evidence, and the unturned one, which no later reading turns (the finalists' choice
    after the first refinement stage tells them apart, ``ipm.search.loop.twin_choice``)."""

    def applies(self, problem, profile) -> bool:
        return reads(profile)

    def __call__(self, cand, trial, settings):
        problem, views = trial.problem, trial.views
        angle, evidence = (0.0, 0.0) if cand.keep_facing else turn_asked(problem, views, cand.z)
        z, changes, settled = read_counts_into(problem, views, cand.z, angle)
        for change in changes:
            trial.record(change, np.nan)
        if not (angle and self.fork):
            return replace(cand, z=z, settled=settled)
        still, changes, still_settled = read_counts_into(problem, views, cand.z, 0.0)
        trial.record("unturned twin", np.nan)
        for change in changes:
            trial.record(change, np.nan)
        return [replace(cand, z=z, settled=settled, credit=cand.credit + evidence),
                replace(cand, z=still, settled=still_settled, keep_facing=True)]


@register
class ReadFinalist(_Read):
    """The counts read into each finalist of the memetic stage (and settled for polish); a turn
    the door asks for forks it into the turned and the unturned twin."""

    name, phase, fork = "read", "finalist", True


@register
class ReadBeforeStage(_Read):
    """The counts read again into each candidate before its Adam run of a stage."""

    name, phase, label = "read again", "refine", "read"
