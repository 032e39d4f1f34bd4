"""The Occam step: each discrete parameter to its simplest value where the views do not ask for more."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.search.moves.base import Move, register
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class SimplifySettings(Settings):
    """Settings of :func:`simplify`."""

    KIND = "diff setting"
    occam_tolerance: Annotated[float, at_least(0.0)] = 0.03
    """A discrete parameter goes to its simplest value (no handle) if that raises the final loss
    by at most this share: one view cannot tell a handle hidden behind the body from none."""
    occam_area: Annotated[float, Range(0.0, 1.0)] = 0.01
    """It goes there too where the pixels the value alone explains (the rise of the pixel loss) are
    at most this share of the object's area in the views: a part that covers a sliver, such as a
    handle standing in for a stem the body cannot make, is not a part the view shows
    (docs/decisions.md, "A part the view barely shows")."""


def simplify(trial, z: np.ndarray, tolerance: float, area: float = 0.0) -> np.ndarray:
    """Set each discrete parameter to its simplest value (``generator.simplest``: name -> value)
    when that raises the loss by at most ``tolerance`` (relative) or by at most ``area`` times the
    object's share of the image (the pixels the value alone explains, as a share of the object's):
    a part the views do not support (a handle hidden behind the body) is dropped. Both sides use
    the same render seeds."""
    problem = trial.problem
    spec, score = problem.spec, trial.scorer((10_001, 10_002))
    for name, value in getattr(problem.generator, "simplest", {}).items():
        i = spec.index[name]
        if spec.from_unit(z[: problem.n_shape])[i] == value:
            continue
        alt = z.copy()
        alt[i] = (value - spec.lower[i]) / (spec.upper[i] - spec.lower[i])
        loss, loss_alt = score(z), score(alt)
        trial.record("fit", loss)
        trial.record(f"{name}={value:g}", loss_alt)
        if loss_alt <= (1.0 + tolerance) * loss or loss_alt - loss <= area * trial.score.object_share:
            z = alt
    return z


@register
class Simplify(Move):
    """:func:`simplify` on the result, for a generator with parts the views may not show (a cup's handle)."""

    name, phase, settings = "simplify", "end", SimplifySettings

    def __call__(self, cand, trial, settings):
        cand.z = simplify(trial, cand.z, settings.occam_tolerance, settings.occam_area)
        return cand
