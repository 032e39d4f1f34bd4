"""Polish: discrete hill climbing over a finalist's many-valued parameters and its half turn."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.problem import Problem
from ipm.search.moves.base import Move, register
from ipm.settings import Settings, at_least


@dataclass(frozen=True)
class PolishSettings(Settings):
    """Settings of :func:`polish`."""

    KIND = "diff setting"
    polish_sweeps: Annotated[int, at_least(0)] = 2
    """Sweeps of the discrete hill climb after the memetic stage, which leaves the counts the views
    settle alone; 0: none (docs/decisions.md, 'Polish')."""
    polish_steps: Annotated[int, at_least(0)] = 6
    """Adam steps given to each neighbour before it is compared."""


def neighbours(problem: Problem, z: np.ndarray) -> dict[str, list[tuple[str, np.ndarray]]]:
    """Discrete neighbours of ``z`` for :func:`polish`, by the parameter they change: each
    many-valued discrete parameter that shapes the object one value down and up (a floor more or
    less, a window more or less on a facade), or, for a categorical one (``Generator.categorical``:
    a roof's type), every other value, since its values have no order (a low hip roof's nearest
    shape is a flat roof, two steps away); and ``yaw``: the half turn (a house's two long sides
    have near-identical silhouettes; its windows and door tell them apart)."""
    spec, n = problem.spec, problem.n_shape
    levels = spec.levels
    active = problem.generator.active(spec.from_unit(z[:n]))
    categorical = {spec.index[name] for name in problem.generator.categorical}
    out = {}
    for i in np.nonzero(spec.discrete & (levels > 2) & active)[0]:
        k = int(round(z[i] * (levels[i] - 1)))
        values = [v for v in range(int(levels[i])) if v != k] if i in categorical else [k - 1, k + 1]
        for v in (v for v in values if 0 <= v < levels[i]):
            alt = z.copy()
            alt[i] = v / (levels[i] - 1)
            out.setdefault(spec.names[i], []).append((f"{spec.names[i]}={spec.lower[i] + v:g}", alt))
    out["yaw"] = [("yaw+180", problem.turned(z, np.pi))]
    return out


def polish(trial, z: np.ndarray, settings: PolishSettings, settled=frozenset()) -> np.ndarray:
    """Parameter by parameter (but those named in ``settled``), try the current point's
    :func:`neighbours` with ``polish_steps`` Adam steps each and move to the first that lowers
    the loss (same render seeds on both sides); up to ``polish_sweeps`` sweeps. The memetic stage
    moves one many-valued gene at a time by chance, so a window count one off on a facade would
    otherwise be left standing."""
    problem, score = trial.problem, trial.scorer((10_003, 10_004))
    best, each = score(z), max(settings.polish_steps, 1)  # evaluations a neighbour costs
    for _ in range(settings.polish_sweeps):
        improved, params = False, {p: v for p, v in neighbours(problem, z).items() if p not in settled}
        planned, spent = each * sum(len(v) for v in params.values()), 0
        trial.plan(planned)  # at most the sweep's neighbours; the bar is set right after the sweep
        for param in params:  # the first of the parameter's neighbours that lowers the loss, if any
            tried = trial.first_lower([(alt, name, settings.polish_steps, score)
                                       for name, alt in neighbours(problem, z).get(param, [])], best)
            spent += each * len(tried)
            if tried and tried[-1][1] < best:
                (z, best), improved = tried[-1], True
        trial.plan(spent - planned)
        if not improved:
            break
    return z


@register
class Polish(Move):
    """:func:`polish` on each finalist of the memetic stage."""

    name, phase, settings = "polish", "finalist", PolishSettings

    def __call__(self, cand, trial, settings):
        cand.z = polish(trial, cand.z, settings, cand.settled)
        return cand
