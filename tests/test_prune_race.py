"""The prune race (``ipm.search.moves.prune``) and the buildings' versions with fewer wings (``pruned``)."""
from __future__ import annotations

import numpy as np
import pytest

from ipm.generators import get_generator
from ipm.generators.buildings.table import L_PLAN, RECTANGLE, T_PLAN, U_PLAN
from ipm.problem import Problem
from ipm.search.moves.prune import PruneSettings, race_evaluations, race_pruned
from ipm.search.trial import Trial


@pytest.fixture(scope="module")
def gen():
    return get_generator("buildings")


def plan_of(gen, x):
    ix = gen.spec.index
    return int(round(x[ix["template"]])), int(round(x[ix["annex"]]))


def with_plan(gen, plan, annex):
    x = gen.presets["house"].copy()
    x[gen.spec.index["template"]], x[gen.spec.index["annex"]] = plan, annex
    return x


def test_pruned_leaves_out_every_set_of_wings_and_keeps_the_others_in_place(gen):
    ix = gen.spec.index
    assert gen.pruned(with_plan(gen, RECTANGLE, 0)) == []
    assert [plan_of(gen, y) for _, y in gen.pruned(with_plan(gen, L_PLAN, 0))] == [(RECTANGLE, 0)]
    assert sorted(plan_of(gen, y) for _, y in gen.pruned(with_plan(gen, T_PLAN, 1))) == \
        [(RECTANGLE, 0), (RECTANGLE, 1), (T_PLAN, 0)]
    u = with_plan(gen, U_PLAN, 0)
    u[ix["wing1_width"]], u[ix["wing1_shift"]], u[ix["wing2_width"]], u[ix["wing2_floors"]] = 0.5, 0.1, 0.7, 3
    versions = dict(gen.pruned(u))
    assert sorted(plan_of(gen, y) for y in versions.values()) == [(RECTANGLE, 0), (L_PLAN, 0), (T_PLAN, 0)]
    right = versions["wing 2"]  # an L's wing is flush with the right end, as a U's second wing
    assert plan_of(gen, right) == (L_PLAN, 0)
    assert (right[ix["wing1_width"]], right[ix["wing1_floors"]]) == (0.7, 3)
    left = versions["wing 1"]  # a T's wing stands mid-side: moved towards the left end, as far as it goes
    assert plan_of(gen, left) == (T_PLAN, 0) and left[ix["wing1_shift"]] == pytest.approx(max(
        0.1 - 0.5 * u[ix["width"]] + 0.25, gen.spec.lower[ix["wing1_shift"]]))
    for y in versions.values():
        np.testing.assert_array_equal(y, gen.spec.clip(y))
        main = [i for i, name in enumerate(gen.spec.names) if not name.startswith("wing")
                and name not in ("template", "annex")]
        np.testing.assert_array_equal(y[main], u[main])


def test_the_race_drops_a_wing_only_where_that_scores_lower_and_keeps_the_fit_untouched_otherwise(gen):
    problem = Problem(gen, np.zeros(3), 1.0)
    ix, n = gen.spec.index, problem.n_shape
    z = problem.initial_z(gen.spec.to_unit(with_plan(gen, L_PLAN, 1)), 0.3)
    w = ix["width"]

    def walk(v, seed=None):  # the steps move the width, whatever the plan
        g = np.zeros_like(v)
        g[w] = 2 * (v[w] - 0.9)
        return float((v[w] - 0.9) ** 2), g

    def lowest_at(plan, annex):
        def score(v, seed=None):
            return float(plan_of(gen, gen.spec.from_unit(v[:n])) != (plan, annex)), np.zeros_like(v)
        return score

    settings = PruneSettings(prune_steps=3, prune_rounds=3)
    best = race_pruned(Trial(problem, walk, lowest_at(RECTANGLE, 1), 0.05, 1.2), z, settings)
    assert plan_of(gen, gen.spec.from_unit(best[:n])) == (RECTANGLE, 1) and best[w] != z[w]
    kept = race_pruned(Trial(problem, walk, lowest_at(L_PLAN, 1), 0.05, 1.2), z, settings)
    np.testing.assert_array_equal(kept, z)  # its own steps discarded
    more = race_pruned(Trial(problem, walk, lowest_at(U_PLAN, 1), 0.05, 1.2), z, settings)
    np.testing.assert_array_equal(more, z)  # a wing is never added
    assert race_evaluations(4, settings) == (4 + 2 + 2) * 3
