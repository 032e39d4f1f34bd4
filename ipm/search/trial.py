"""What a move of the search is given: its candidates, a trial helper (Adam runs, races, scores) and the trace."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pandas as pd
from tqdm import tqdm

from ipm import lanes
from ipm.optim.memetic import Individual, adam_steps, step_evaluations
from ipm.problem import Problem

TRACE_COLUMNS = ["stage", "res", "eval", "origin", "loss", "best", "seconds"]
"""Columns of trace.csv: one row per evaluation, plus a row per candidate a stage scores by name."""


@dataclass
class Candidate:
    """A point the search carries between stages, and the parameters the views settle for it."""

    z: np.ndarray
    settled: frozenset[str] = field(default_factory=frozenset)
    """Counts the views settle (read off class masks, or of sides no view faces): polish leaves them."""
    keep_facing: bool = False
    """The twin left unturned where the views' marker asked for a turn: no later reading turns it."""
    credit: float = 0.0
    """Evidence the loss does not weigh (the marker's pixel share where the point was turned to it),
    taken off its loss where it is compared with its twins."""
    lineage: int = 0
    """The finalist it came from: twins share it (``ipm.search.loop.twin_choice``)."""


def scorer(objective, seeds: tuple[int, ...]) -> Callable[[np.ndarray], float]:
    """Loss of a point averaged over fixed render ``seeds`` (both sides of a comparison alike)."""
    return lambda x: float(np.mean([objective(x, seed=s)[0] for s in seeds]))


class Tracker:
    """The trace rows and the progress bar of one search; ``best`` is the running best loss."""

    def __init__(self, total: int, progress: bool):
        self.rows, self.t0 = [], time.perf_counter()
        self.stage, self.res, self.best = "memetic", 0, np.inf
        self.bar = tqdm(total=total, desc="reconstruct", unit="eval", disable=not progress, leave=False)

    def row(self, stage: str, res: int, origin: str, loss: float, best: float) -> None:
        self.rows.append((stage, res, len(self.rows), origin, loss, best, time.perf_counter() - self.t0))

    def on_eval(self, ind: Individual) -> None:
        """A row for an evaluation of the current stage (at the width its steps render); a try's
        beside others when the try is kept (``ipm.lanes``)."""
        lanes.later(self._evaluated, ind.origin, ind.loss, ind.best_loss)

    def _evaluated(self, origin: str, loss: float, best_loss: float) -> None:
        self.best = min(self.best, best_loss)
        self.row(self.stage, self.res, origin, loss, self.best)
        self.bar.update(1)
        self.bar.set_postfix(stage=self.stage, res=self.res, best=f"{self.best:.5f}")

    def extend(self, evaluations: int) -> None:
        """The progress bar's total grown by ``evaluations`` (a stage the search adds as it goes)."""
        self.bar.total += evaluations
        self.bar.refresh()

    def recorder(self, stage: str, res: int) -> Callable[[str, float], None]:
        """A trace row per candidate a stage scores by name, at the width it scores."""
        return lambda name, loss: lanes.later(lambda: self.row(stage, res, name, loss, min(self.best, loss)))

    def enter(self, stage: str, res: int, reset: bool = False) -> None:
        self.stage, self.res = stage, res
        if reset:
            self.best = np.inf

    def frame(self) -> pd.DataFrame:
        self.bar.close()
        return pd.DataFrame(self.rows, columns=TRACE_COLUMNS)


def survivors(candidates: int) -> int:
    """How many of ``candidates`` go on to a race's next round (:meth:`Trial.rounds`): the better
    half, at least two."""
    return min(candidates, max(2, (candidates + 1) // 2))


class Trial:
    """How a move tries points: Adam steps under ``steps`` (an objective), compared under ``score``
    (an objective at the stage's width); every evaluation and scored candidate goes to the trace."""

    def __init__(self, problem: Problem, steps, score, lr: float, reject_ratio: float, views=None, profile=None,
                 on_eval: Callable = lambda ind: None, record: Callable = lambda name, loss: None,
                 plan: Callable[[int], None] = lambda evaluations: None, side: lanes.Lanes | None = None):
        self.problem, self.steps, self.score, self.views, self.profile = problem, steps, score, views, profile
        self.side = side or lanes.Lanes()
        """Where independent tries run (:meth:`tries`, :meth:`first_lower`): side by side on its threads."""
        self.lr, self.reject_ratio = lr, reject_ratio
        self.on_eval, self.record = on_eval, record
        self.plan = plan
        """Tells the progress bar of evaluations a move now knows it will spend (negative: fewer
        than it said); for moves whose cost depends on the candidate (``Move.cost`` 0)."""

    def scorer(self, seeds: tuple[int, ...]) -> Callable[[np.ndarray], float]:
        """The ``score`` objective's loss averaged over fixed render ``seeds``."""
        return scorer(self.score, seeds)

    def tried(self, start: np.ndarray, name: str, steps: int, score: Callable,
              clip: Callable | None = None) -> tuple[np.ndarray, float]:
        """The best point of ``steps`` Adam steps from ``start`` (``start`` itself for none) under the
        ``steps`` objective, projected by ``clip`` (default ``problem.clip``), and its ``score``,
        recorded as ``name``."""
        problem = self.problem
        ind = Individual(start, problem.key(start), name, lr=self.lr * 0.4)
        adam_steps(ind, steps, self.steps, clip or problem.clip, self.reject_ratio, self.on_eval)
        cand = ind.z if ind.best_z is None else ind.best_z
        loss = score(cand)
        self.record(name, loss)
        return cand, loss

    def _task(self, start: np.ndarray, name: str, steps: int, score: Callable,
              clip: Callable | None = None) -> lanes.Task:
        """:meth:`tried` as a task: it draws a render seed an evaluation of its fresh individual's steps."""
        return lanes.Task(lambda: self.tried(start, name, steps, score, clip),
                          {self.steps: step_evaluations(steps, fresh=True)})

    def tries(self, tries: list[tuple]) -> list[tuple[np.ndarray, float]]:
        """:meth:`tried` of each (start, name, steps, score[, clip]), side by side where there are
        threads, in order: the same points, losses and trace as one after another."""
        return self.side.map([self._task(*t) for t in tries])

    def first_lower(self, tries: list[tuple], loss: float) -> list[tuple[np.ndarray, float]]:
        """:meth:`tries` up to the first whose loss is below ``loss`` (included), as if the later
        ones were never tried."""
        return self.side.first([self._task(*t) for t in tries], lambda tried: tried[1] < loss)

    def rounds(self, pool: list[tuple[str, np.ndarray]], steps: int, rounds: int,
               score: Callable) -> list[tuple[str, np.ndarray, float]]:
        """The starts of ``pool`` (name, point) raced over ``rounds``: each round gives every start left
        ``steps`` Adam steps from where it stands and keeps the better half (at least two,
        :func:`survivors`) for the next; the last round's (name, point, score), lowest first."""
        tried = []
        for r in range(rounds):
            tried = [(tag, *t) for (tag, _), t in zip(pool, self.tries(
                [(start, tag if r == 0 else f"{tag} (round {r + 1})", steps, score) for tag, start in pool]))]
            tried.sort(key=lambda t: t[2])
            if r < rounds - 1:
                tried = tried[:survivors(len(tried))]
            pool = [(tag, point) for tag, point, _ in tried]
        return tried

    def race(self, z: np.ndarray, name: str, starts: list[tuple[str, np.ndarray]], steps: int, margin: float,
             score: Callable) -> np.ndarray:
        """``z`` (recorded as ``name``) and each of ``starts`` (name, point) given ``steps`` Adam steps
        and compared by ``score``: the lowest start replaces ``z`` only if its loss is lower than
        ``z``'s by more than ``margin`` (a fraction). How sweeps try starts the fit would not reach."""
        kept, *tried = self.tries([(z, name, steps, score)] + [(alt, alt_name, steps, score) for alt_name, alt in starts])
        best = min(tried, key=lambda start: start[1], default=kept)
        return best[0] if best[1] < kept[1] * (1 - margin) else kept[0]
