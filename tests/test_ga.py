"""The tree GA and its statistics on analytic objectives (no rendering)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ipm.errors import UserError
from ipm.generators.base import make_spec
from ipm.optim import ALGORITHMS
from ipm.optim.ga import ElementaryGA, TreeGA, crossover, genes_to_change, mutate, plan_tree
from ipm.optim.ga_settings import GA_PROFILES, get_settings
from ipm.optim.ga_statistics import GeneStatistics, collect_statistics, random_genes, snap

SPEC = make_spec([(f"c{i}", -1.0, 1.0, False, 0.0) for i in range(8)]
                 + [("k5", 0, 4, True, 0), ("flag", 0, 1, True, 0), ("k10", 0, 9, True, 0)])
TARGET = np.array([0.15, 0.6, 0.6, 0.3, 0.8, 0.4, 0.55, 0.25])
WEIGHT = np.array([1.0, 1.0, 1.0, 0.8, 0.6, 0.5, 0.4, 0.3])


def mixed_loss(u: np.ndarray, shift: float = 0.0) -> float:
    """Deceptive but structured: gene 0 has a narrow global basin at 0.15 and a broad local one
    at 0.8; genes 1-2 interact; the binary ``flag`` decides where gene 3 should be (and is worth
    0.05); two integer genes have their own optima. Minimum 0 at TARGET, k5=3, flag=1, k10=7."""
    x, c = SPEC.from_unit(u), np.asarray(u)[:8]
    t = np.clip(TARGET + shift, 0.0, 1.0)
    g0 = min(8 * (c[0] - t[0]) ** 2, 0.08 + 0.3 * (c[0] - 0.8) ** 2)
    flag = x[9]
    inter = 2.0 * (c[1] - c[2]) ** 2 + (c[3] - (t[3] if flag else 1 - t[3])) ** 2 + 0.05 * (1 - flag)
    return float(g0 + np.sum(WEIGHT[1:] * (c[1:] - t[1:]) ** 2) + inter
                 + 0.04 * abs(x[8] - 3) + 0.01 * abs(x[10] - 7))


SMALL = get_settings("default", budget=600, depth=1, initial_population=40, max_population=30)


def on_grid(u: np.ndarray) -> bool:
    return bool(np.all((u >= 0) & (u <= 1)) and np.allclose(snap(SPEC, u), u))


@pytest.fixture(scope="module")
def family_stats() -> GeneStatistics:
    """Statistics over a family of three targets around TARGET (the paper's F)."""
    return collect_statistics(SPEC, lambda u: np.array([mixed_loss(u, s) for s in (-0.05, 0.0, 0.05)]),
                              n_samples=3000, bins=10, seed=1)


def test_profiles_and_overrides():
    assert GA_PROFILES["paper"].initial_population == 125 and GA_PROFILES["paper"].max_population == 100
    assert GA_PROFILES["paper"].budget == 5000 and GA_PROFILES["paper"].mutation_candidates == 500
    assert get_settings("smoke", budget=200).budget == 200
    with pytest.raises(UserError, match="unknown GA profile"):
        get_settings("fast")
    with pytest.raises(UserError, match="unknown GA setting"):
        get_settings("smoke", popsize=3)
    with pytest.raises(UserError, match="max_population"):
        get_settings("smoke", max_population=1)
    assert ALGORITHMS["ga"] is TreeGA
    for name, s in GA_PROFILES.items():  # every profile's tree plan spends exactly its budget
        nodes = plan_tree(s, s.budget)
        assert sum(n.budget for n in nodes) == s.budget and len(nodes) == s.n_nodes, name


def test_random_genes_and_snap_stay_on_the_grid(rng):
    u = random_genes(SPEC, rng, 2000)
    assert on_grid(u)
    x = SPEC.from_unit(u)
    for i, levels in ((8, 5), (9, 2), (10, 10)):  # every integer value, each about equally often
        counts = np.bincount(x[:, i].astype(int), minlength=levels)
        assert len(counts) == levels and counts.min() > 0.6 * 2000 / levels
    moved = snap(SPEC, u + 0.03)
    np.testing.assert_array_equal(snap(SPEC, moved), moved)  # idempotent
    np.testing.assert_array_equal(SPEC.from_unit(moved), SPEC.from_unit(u + 0.03))  # same values as from_unit


def test_one_point_crossover_takes_a_prefix_and_a_suffix(rng):
    a, b = rng.random(11), rng.random(11)
    for cut in range(1, 11):
        child = crossover(a, b, cut)
        np.testing.assert_array_equal(child[:cut], a[:cut])
        np.testing.assert_array_equal(child[cut:], b[cut:])
    # in the GA: every child without mutation is a prefix of one survivor + the suffix of another
    ga = ElementaryGA(SPEC, get_settings("smoke", mutation_chance=0.0, max_population=20), seed=3)
    first = ga.ask()
    ga.tell([mixed_loss(u) for u in first])
    children = ga.ask()
    parents = ga._survivors
    splits = [any(np.array_equal(child[:c], p[:c]) and np.array_equal(child[c:], q[c:])
                  for c in range(1, 11) for p in parents for q in parents) for child in children]
    assert np.mean(splits) > 0.8  # the rest: copies of a survivor, which are always mutated


def test_mutation_changes_n_times_m_genes_on_the_grid(rng):
    s = get_settings("default", mutation_genes=0.3, mutation_n=1.0)
    k = genes_to_change(s, len(SPEC))
    assert k == round(0.3 * 11)
    g = random_genes(SPEC, rng, 1)[0]
    weights = np.full(11, 1 / 11)
    changed = []
    for _ in range(300):
        m = mutate(SPEC, g, rng, k, weights, 1, None)
        assert on_grid(m)
        changed.append(np.sum(m != g))
    changed = np.array(changed)
    assert changed.max() <= k and changed.mean() > k - 0.6  # discrete genes may redraw their value
    # genes are chosen in proportion to the weights: gene 2 only
    w = np.full(11, 1e-9)
    w[2] = 1.0
    m = mutate(SPEC, g, rng, 1, w / w.sum(), 1, None)
    assert np.flatnonzero(m != g).tolist() in ([2], [])
    # with a quality, the best of the candidates is kept
    best = mutate(SPEC, g, rng, 1, w / w.sum(), 200, lambda cand: -np.abs(cand[:, 2] - 0.9))
    assert abs(best[2] - 0.9) < 0.02


def test_statistics_find_the_gene_that_matters():
    spec = make_spec([(f"g{i}", 0.0, 1.0, False, 0.5) for i in range(5)] + [("n", 0, 3, True, 0)])

    def f(u):  # gene 2 dominates (best near 0.3), gene 0 matters a little, the others not at all
        return 5.0 * (u[2] - 0.3) ** 2 + 0.2 * (u[0] - 0.5) ** 2

    st = collect_statistics(spec, f, n_samples=600, bins=5, seed=0)
    assert int(np.argmax(st.v)) == 2
    assert st.v[0] > 5 * st.v[[1, 3, 4, 5]].max()
    assert st.v[[1, 3, 4, 5]].max() < 1e-9
    assert int(np.argmax(st.q[2])) == 1  # bin [0.2, 0.4) holds the good samples
    assert st.q[2, 1] > 3 and st.q[2, 4] < -3
    assert st.p0 == pytest.approx(0.1, abs=0.01)
    assert st.counts.sum(axis=1).tolist() == [1200] * 6
    good, bad = np.full(6, 0.5), np.full(6, 0.5)
    good[2], bad[2] = 0.3, 0.9
    assert st.quality(good) > st.quality(bad)


def test_statistics_roundtrip_and_malformed_files(tmp_path, family_stats):
    path = tmp_path / "stats.json"
    family_stats.save(path)
    back = GeneStatistics.load(path)
    assert back.names == family_stats.names and back.epsilon.shape == (3,)
    np.testing.assert_array_equal(back.counts, family_stats.counts)
    np.testing.assert_allclose(back.q, family_stats.q)
    np.testing.assert_allclose(back.v, family_stats.v)
    assert [p.name for p in tmp_path.iterdir()] == ["stats.json"]  # atomic: no leftovers

    d = json.loads(path.read_text())
    broken = {
        "notjson.json": "{not json",
        "format.json": json.dumps({**d, "format": "other"}),
        "shape.json": json.dumps({**d, "counts": d["counts"][:-1]}),
        "negative.json": json.dumps({**d, "v": [-1.0] * len(d["v"])}),
        "missing.json": json.dumps({k: v for k, v in d.items() if k != "good"}),
        "good_gt_counts.json": json.dumps({**d, "good": [[c + 1 for c in row] for row in d["counts"]]}),
        "h.json": json.dumps({**d, "h": 1.0}),
        "n_samples.json": json.dumps({**d, "n_samples": 0}),
        "prior.json": json.dumps({**d, "prior": "2"}),
    }
    for name, text in broken.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(UserError):
            GeneStatistics.load(tmp_path / name)
    with pytest.raises(UserError, match=r"h\.json: field h must be > 0 and < 1, got 1\.0"):
        GeneStatistics.load(tmp_path / "h.json")
    with pytest.raises(UserError, match="not found"):
        GeneStatistics.load(tmp_path / "absent.json")
    other = make_spec([("a", 0.0, 1.0, False, 0.0)])
    with pytest.raises(UserError, match="statistics are for genes"):
        TreeGA(other, SMALL, family_stats)


def test_same_seed_same_trace():
    runs = [TreeGA(SPEC, SMALL, None, seed).minimize(mixed_loss, progress=False) for seed in (7, 7, 8)]
    (u1, l1, t1), (u2, l2, t2), (_, _, t3) = runs
    np.testing.assert_array_equal(u1, u2)
    t1, t2, t3 = (t.drop(columns="seconds") for t in (t1, t2, t3))  # wall time is the one thing that differs
    assert l1 == l2 and t1.equals(t2) and not t1.equals(t3)
    assert len(t1) == SMALL.budget and t1["eval"].tolist() == list(range(SMALL.budget))
    assert np.all(np.diff(t1["best"]) <= 0) and t1["best"].iloc[-1] == l1 == t1["loss"].min()
    assert mixed_loss(u1) == l1 and on_grid(u1)


def test_ga_beats_random_search_at_equal_budget(family_stats):
    """Median best loss over 5 seeds; the statistics help once they are well estimated."""
    seeds = range(5)
    rand = [min(mixed_loss(u) for u in random_genes(SPEC, np.random.default_rng(100 + s), SMALL.budget))
            for s in seeds]
    plain = [TreeGA(SPEC, SMALL, None, s).minimize(mixed_loss, progress=False)[1] for s in seeds]
    guided = [TreeGA(SPEC, SMALL, family_stats, s).minimize(mixed_loss, progress=False)[1] for s in seeds]
    assert np.median(plain) < 0.2 * np.median(rand)
    assert np.median(guided) < 0.2 * np.median(rand)
    assert np.median(guided) < np.median(plain)


def test_tree_seeds_higher_nodes_with_the_childrens_best():
    s = get_settings("smoke", budget=150, depth=2, initial_population=12, max_population=10)
    tree = TreeGA(SPEC, s, seed=0)
    tree.minimize(mixed_loss, progress=False)
    assert [n.level for n in tree.nodes] == [0, 0, 1, 0, 0, 1, 2]
    assert sum(n.ga.evaluations for n in tree.nodes) == 150 == len(tree.trace)
    seconds = tree.trace["seconds"]  # wall time since the plan, for the report's convergence plots
    assert (seconds >= 0).all() and seconds.is_monotonic_increasing
    for node in tree.nodes:
        if not node.children:
            assert len(node.ga.initial) == 12
            continue
        # the node's starting population is the best 5 of each child's final population
        expected = np.concatenate([tree.nodes[c].ga.best(5)[0] for c in node.children])
        got = node.ga.initial
        assert sorted(map(bytes, got)) == sorted(map(bytes, expected))
        assert tree.trace.query(f"node == {node.index}")["generation"].min() == 1  # nothing re-evaluated
    assert tree.root.ga.best_loss == tree.best_loss == tree.trace["loss"].min()
    # nodes run children first: the trace's node column never goes back to a finished node
    order = tree.trace["node"].to_numpy()
    assert np.all(np.diff(order) >= 0)


def test_ask_tell_misuse():
    tree = TreeGA(SPEC, get_settings("smoke"), seed=0)
    with pytest.raises(RuntimeError):
        tree.tell([1.0])
    batch = tree.ask()
    with pytest.raises(RuntimeError):
        tree.ask()
    with pytest.raises(ValueError, match="expected 12 losses"):
        tree.tell(np.zeros(len(batch) + 1))
    tree.tell([np.nan] + [1.0] * (len(batch) - 1))  # NaN counts as the worst, not as an error
    assert tree.best_loss == 1.0
    while not tree.done:
        tree.tell(np.ones(len(tree.ask())))
    with pytest.raises(RuntimeError, match="budget"):
        tree.ask()
    with pytest.raises(UserError, match="below"):
        TreeGA(SPEC, get_settings("paper"), budget=400)
    seen = []
    tree = TreeGA(SPEC, get_settings("smoke"), seed=1)
    _, _, trace = tree.minimize(mixed_loss, budget=60, progress=False, on_eval=lambda row, u: seen.append(row))
    assert len(seen) == len(trace) == 60 and seen[-1]["best"] == trace["best"].iloc[-1]
