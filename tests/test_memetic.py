"""The memetic algorithm and Adam on analytic objectives (no rendering)."""
from __future__ import annotations

import numpy as np
import pytest

from ipm.optim.adam import adam_init, adam_update
from ipm.optim.memetic import (Individual, adam_steps, log_quality, memetic, merge_bins, move_discrete,
                               share_budget)
from ipm.profiles import PROFILES, get_profile
from ipm.errors import UserError


def test_adam_first_step_is_lr_times_sign():
    step, state = adam_update(adam_init(np.zeros(3)), np.array([2.0, -0.5, 0.0]), 0.1)
    np.testing.assert_allclose(step, [-0.1, 0.1, 0.0], atol=1e-6)
    assert state.t == 1


def test_budget_sharing_sums_and_prefers_low_loss():
    n = share_budget(160, log_quality(np.array([0.01, 0.02, 0.2]), np.zeros(3), it=5))
    assert n.sum() == 160 and n[0] > n[1] > n[2]
    stalled = share_budget(100, log_quality(np.array([0.01, 0.01]), np.array([0, 400]), it=0))
    assert stalled[0] > stalled[1]


def test_merge_keeps_best_per_bin():
    mk = lambda yaw, loss, key=(1,): Individual(np.array([0.5, yaw]), key, "t", loss=loss, best_loss=loss)  # noqa: E731
    pop = [mk(0.1, 3.0), mk(0.2, 1.0), mk(3.0, 2.0), mk(0.1, 0.5, key=(0,))]
    merged = merge_bins(pop, n_shape=1, bins=16)
    assert [i.best_loss for i in merged] == [0.5, 1.0, 2.0]
    # an object that looks the same turned has one bin per topology: its turned twins merge
    free = merge_bins(pop, n_shape=1, bins=16, yaw_free=lambda z: True)
    assert [i.best_loss for i in free] == [0.5, 1.0]


def test_rejected_steps_halve_the_rate_and_keep_the_best():
    calls = []

    def evaluate(z):  # a loss that explodes away from 0: every step is rejected
        calls.append(z.copy())
        return (1.0, np.ones_like(z)) if len(calls) == 1 else (10.0, np.ones_like(z))

    ind = Individual(np.zeros(2), (), "t", lr=0.1)
    adam_steps(ind, 4, evaluate, lambda z: z, 1.2, lambda i: None)
    assert len(calls) == 4 and ind.lr == pytest.approx(0.1 / 8) and ind.best_loss == 1.0
    np.testing.assert_array_equal(ind.best_z, np.zeros(2))


def test_memetic_finds_the_minimum_of_a_mixed_problem(rng):
    """Two 'topologies' (discrete gene 0) with different optima; the better one must win."""
    target = {0: np.array([0.2, 0.7]), 1: np.array([0.6, 0.3])}
    offset = {0: 0.05, 1: 0.0}
    key_of = lambda z: (int(round(z[0])),)  # noqa: E731

    def evaluate(z):
        k = key_of(z)[0]
        d = z[1:3] - target[k]
        return float(offset[k] + d @ d), np.concatenate([[0.0], 2 * d, [0.0]])

    clip = lambda z: np.concatenate([np.clip(z[:3], 0, 1), [np.mod(z[3], 2 * np.pi)]])  # noqa: E731
    prof = get_profile("default", population=8, ga_iterations=6, adam_per_iteration=80).memetic
    init = [Individual(clip(np.concatenate([[k], rng.random(2), [rng.random() * 6]])), (k,), "r", lr=0.05)
            for k in (0, 0, 0, 0, 1, 0, 0, 0)]
    final = memetic(init, evaluate, clip, key_of, 3, np.array([2, 0, 0]), prof, rng)
    best = final[0]
    assert [i.best_loss for i in final] == sorted(i.best_loss for i in final)
    assert best.key == (1,) and best.best_loss < 1e-3
    np.testing.assert_allclose(best.best_z[1:3], target[1], atol=0.03)


def test_profiles():
    paper = get_profile("paper")
    assert paper.memetic.ga_iterations == 20 and paper.memetic.adam_per_iteration == 160
    assert paper.memetic.population == 16 and paper.loop.refine_res == (256, 512)
    assert set(PROFILES) == {"paper", "default", "smoke"}
    with pytest.raises(UserError, match="unknown profile"):
        get_profile("fast")
    with pytest.raises(UserError, match="unknown renderer 'opengl'"):
        get_profile("smoke", renderer="opengl")


def test_discrete_moves_cover_many_valued_genes(rng):
    """A two-valued gene flips without a random draw (two-valued searches keep their stream); a
    many-valued one always changes, stays on its values, and reaches neighbours and far values."""
    state = rng.bit_generator.state
    np.testing.assert_array_equal(move_discrete(np.array([0.0, 1.0, 0.2]), np.array([2, 2, 2]), rng), [1, 0, 1])
    assert rng.bit_generator.state == state
    levels = np.array([9])
    seen = []
    for _ in range(400):
        u = move_discrete(np.array([4 / 8]), levels, rng)[0]
        k = u * 8
        assert abs(k - round(k)) < 1e-9 and 0 <= k <= 8 and round(k) != 4
        seen.append(round(k))
    counts = np.bincount(seen, minlength=9)
    assert counts[3] + counts[5] > 0.5 * len(seen)  # a step of one, about half the time plus draws
    assert all(counts[k] > 0 for k in (0, 1, 2, 6, 7, 8))  # and any other value
    assert move_discrete(np.array([0.0]), levels, rng)[0] > 0 and move_discrete(np.array([1.0]), levels, rng)[0] < 1
