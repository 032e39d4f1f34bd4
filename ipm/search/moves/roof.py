"""The roof race: every kind of a categorical part (a roof), as it stands and turned a quarter, raced.

A generator that lists this move has ``categorical`` parameters and ``split_roof``; with
``decide_turns``, a front (``marker``) and ``quarter_turned`` (``ipm.search.moves.counts``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.search.moves.base import Move, register
from ipm.search.moves.counts import read_counts_into, reads, turned
from ipm.search.trial import survivors
from ipm.settings import UNIT, Settings, at_least


@dataclass(frozen=True)
class RoofSettings(Settings):
    """Settings of :func:`decide`."""

    KIND = "diff setting"
    decide_steps: Annotated[int, at_least(0)] = 0
    """Adam steps each value of a categorical parameter (``Generator.categorical``: the roof type), and each
    turned, gets before the last refinement stage; 0: none (docs/decisions.md, 'Roof race')."""
    decide_rounds: Annotated[int, at_least(1)] = 1
    """Rounds of the race: after each, the better half of the candidates (at least two) get ``decide_steps``
    more Adam steps; 1: the lowest loss after one round wins (docs/decisions.md, 'Roof race')."""
    decide_turns: bool = True
    """Whether the race also tries each value turned a quarter (width and depth traded, the counts read in
    again) for a generator with a front (``marker``) (docs/decisions.md, 'Roof race')."""
    decide_shares: tuple[Annotated[float, UNIT], ...] = ()
    """Shares of the object's height the race also tries giving to a pitched roof, for each value and each
    turn (``split_roof``: the walls take the rest); (): none (docs/decisions.md, 'Height shares')."""
    decide_kinds: Annotated[int, at_least(0)] = 0
    """Where a categorical parameter has more values than this, a first round gives every value as it stands
    ``decide_steps``, and only the best ``decide_kinds`` go on to be tried turned and with the height shares;
    0: every value with its turns and shares from the start (docs/decisions.md, 'Roof race')."""


def decide_evaluations(candidates: int, settings: RoofSettings, values: int | None = None) -> int:
    """Adam steps :func:`decide` spends on ``candidates`` starts of one parameter of ``values`` values
    (progress bar)."""
    total = 0
    if values is not None and 0 < settings.decide_kinds < values:  # the first round over the values alone
        total += values * settings.decide_steps
        candidates = candidates * settings.decide_kinds // values
    for _ in range(settings.decide_rounds):
        total += candidates * settings.decide_steps
        candidates = survivors(candidates)
    return total


def decide(trial, z: np.ndarray, settings: RoofSettings, recount=None) -> np.ndarray:
    """Every value of each categorical parameter (a roof's type) given ``decide_steps`` Adam steps
    from ``z``, the current value too (none is favoured by a longer refinement), and compared under
    the trial's score (same render seeds): the lowest wins. Polish's few steps at the memetic
    resolution cannot carry a flat roof to a hip roof's basin (its walls and slope must move
    together). With ``recount`` (``z`` -> ``z`` with the counts the views show read in) each value
    is also tried turned a quarter (:func:`~ipm.search.moves.counts.turned`): a near-square house
    fitted a quarter off with a pyramid-like hip roof matches a gable roof only turned, since a
    gable's ridge has a direction. With ``decide_rounds`` above 1 the candidates race: after each
    round the better half (at least two) get ``decide_steps`` more from where they stand, since
    the current value starts converged and a new roof is still descending when the first round
    ends. With ``decide_shares`` each value (and each turned) also starts with the height shared
    anew between roof and walls (``split_roof``). With ``decide_kinds`` below the number of values
    (nine roof kinds), a first round ranks the values as they stand and only the best go on to
    their turns and shares."""
    problem = trial.problem
    spec, n, gen = problem.spec, problem.n_shape, problem.generator
    score = trial.scorer((10_005, 10_006))
    for name in gen.categorical:
        i, on = spec.index[name], gen.active(spec.from_unit(z[:n]))
        if settings.decide_steps <= 0 or not on[i]:
            continue
        levels = int(spec.levels[i])
        values = []
        for k in range(levels):
            alt = z.copy()
            alt[i] = k / (levels - 1)
            values.append((f"{name}={spec.lower[i] + k:g}", alt))
        kept = range(levels)
        if 0 < settings.decide_kinds < levels:  # every value as it stands first; the best go on
            tried = trial.tries([(start, tag, settings.decide_steps, score) for tag, start in values])
            kept = sorted(np.argsort([loss for _, loss in tried], kind="stable")[:settings.decide_kinds])
        pool = []
        for k in kept:
            value, alt = values[k]
            splits = [(share, gen.split_roof(spec.from_unit(alt[:n]), share)) for share in settings.decide_shares]
            for tag, start in [(value, alt)] + [(f"{value} roof {share:g}", problem.with_shape(alt, x))
                                                for share, x in splits if x is not None]:
                pool += [(tag, start)] + ([(f"{tag} turned", recount(turned(problem, start, np.pi / 2)))]
                                          if recount is not None else [])
        z = trial.rounds(pool, settings.decide_steps, settings.decide_rounds, score)[0][1]
    return z


@register
class RoofRace(Move):
    """:func:`decide` before the last stage: steps at the previous stage's width, scores at this one's."""

    name, phase, settings, label, steps_before = "roof", "last", RoofSettings, "decide", True

    def turns(self, problem, profile) -> bool:
        return profile.of(RoofSettings).decide_turns and bool(problem.generator.marker)

    def applies(self, problem, profile) -> bool:
        return profile.of(RoofSettings).decide_steps > 0 and bool(problem.generator.categorical)

    def cost(self, problem, profile) -> int:
        settings, spec = profile.of(RoofSettings), problem.spec
        return sum(decide_evaluations(int(spec.levels[spec.index[c]]) * (1 + self.turns(problem, profile))
                                      * (1 + len(settings.decide_shares)), settings, int(spec.levels[spec.index[c]]))
                   for c in problem.generator.categorical)

    def __call__(self, cand, trial, settings):
        recount = None
        if self.turns(trial.problem, trial.profile):
            recount = ((lambda z: read_counts_into(trial.problem, trial.views, z)[0]) if reads(trial.profile)
                       else (lambda z: z))
        cand.z = decide(trial, cand.z, settings, recount)
        return cand
