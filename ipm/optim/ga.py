"""The paper's genetic algorithm for non-differentiable generators: a tree of elementary GAs.

Paper, section "Non-differentiable Case / Genetic Algorithm Implementation"; everything works in
the unit cube of a :class:`~ipm.generators.base.ParamSpec` (discrete genes on their grid) and
*minimises* a loss (the paper maximises a similarity; "better" below means lower loss).

**Elementary GA** (:class:`ElementaryGA`, ask/tell). Each generation removes the worse half of
the population and fills the vacant places, up to ``max_population``, with children: one-point
crossover of two parents drawn from the survivors by fitness-proportionate selection, then,
with probability ``M_chance``, the paper's mutation:

1. ``n * M_genes`` genes (here ``round(n * M_genes * N)``, at least 1, of the ``N`` genes) are
   drawn without replacement with probability proportional to ``V(k)`` and get new random values;
2. the mutant's predicted quality ``Q(G')`` is computed from the statistics (no evaluation);
3. steps 1-2 are repeated ``mutation_candidates`` times (500 in the paper) and the mutant with
   the best ``Q`` is kept.

**Statistics** (:class:`GeneStatistics`, :func:`collect_statistics`), gathered once per
generator on random samples ``x`` (a cached pipeline stage)::

    V(k)   = mean | f(x + h e_k) - f(x) | / h                 (average rate of change of gene k)
    P_ij   = P( x is good | (j-1)/B < x_i < j/B )               (paper: P(F(x) > eps | ...))
    P_0    = P( x is good )
    Q_ij   = sign(P_ij - P_0) * max(P_ij, P_0) / min(P_ij, P_0)
    Q(G)   = sum_i Q(i, floor(G_i * B))

"Good" is the paper's ``F(x) > eps`` for a similarity; for a loss it is ``loss <= eps_f`` with
``eps_f`` the ``good_fraction`` quantile of that objective's sample losses, one threshold per
member ``f`` of the family ``F`` (losses of different targets need not share a scale).

**Tree of GAs** (:class:`TreeGA`): a complete binary tree of ``2**depth`` leaves; leaves start
from random populations of ``initial_population``, every higher node from the best halves of
its two children's final populations (already evaluated), and the root's best is the answer.
The paper gives each elementary GA "a fixed number of generations"; so after the leaves'
initial populations the evaluation budget is split equally over all nodes (the rounding
remainder goes to the root).

Choices the paper leaves open are fields of :class:`GASettings` with their reasons.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from ipm.errors import UserError
from ipm.optim import ALGORITHMS

if TYPE_CHECKING:
    import pandas as pd

    from ipm.generators.base import ParamSpec


# ----------------------------------------------------------------------------------------------
# Settings


@dataclass(frozen=True)
class GASettings:
    """Settings of the tree GA and of its statistics stage (profiles: ``GA_PROFILES``)."""

    budget: int = 5000
    """Loss evaluations of the whole tree, after the statistics (5000: the authors' code configuration,
    ``docs/design``, "Tree GA"; the paper's text gives a limit of 50 000 for trees and 5000 for
    its memetic stage)."""
    depth: int = 2
    """Levels above the leaves: ``2**depth`` leaves, ``2**(depth+1) - 1`` elementary GAs. The
    paper's figure shows a binary tree but no size; 2 (4 leaves, 7 GAs) leaves each GA about 13
    generations at the paper's budget."""
    initial_population: int = 125
    """Random individuals of a leaf's first generation (the authors' code: ``docs/design``,
    "Tree GA")."""
    max_population: int = 100
    """Population after each generation: survivors plus children (the authors' code: ``docs/design``,
    "Tree GA")."""
    mutation_chance: float = 0.5
    """``M_chance``: probability that a child is mutated (not given in the paper)."""
    mutation_genes: float = 0.1
    """``M_genes``: share of the genes a mutation changes (not given in the paper)."""
    mutation_n: float = 1.0
    """``n``: multiplier of ``M_genes``; a mutation changes ``round(n * M_genes * N)`` genes (>= 1)."""
    mutation_candidates: int = 500
    """Mutants tried per mutation, the best by ``Q`` kept (500 in the paper). Without statistics
    ``Q`` says nothing and one mutant is drawn."""
    fitness_floor: float = 0.1
    """Fitness of the worst survivor relative to the best's ``1 + fitness_floor``: fitness is the
    loss rescaled linearly over the survivors (best 1, worst 0) plus this floor, so selection is
    proportional to it whatever the loss's sign and scale."""
    bins: int = 10
    """``B``: bins per gene of the statistics (not given in the paper)."""
    stats_samples: int = 2000
    """Random points ``x`` of the statistics stage; each costs 2 evaluations (``x`` and
    ``x + h e_k``). The paper says "a large sample"."""
    stats_h: float = 0.05
    """``h``: finite-difference step of ``V`` in the unit cube (discrete genes: at least one
    grid level)."""
    good_fraction: float = 0.1
    """``eps`` as a quantile: the best ``good_fraction`` of each objective's samples are good."""
    stats_prior: float = 2.0
    """Pseudo-samples at ``P_0`` added to every bin, so an empty or rare bin has ``P_ij`` near
    ``P_0`` (``Q`` near 0) instead of 0 (``Q`` infinite)."""

    def __post_init__(self):
        ints = {"budget": 1, "depth": 0, "initial_population": 2, "max_population": 2,
                "mutation_candidates": 1, "bins": 1, "stats_samples": 1}
        for name, low in ints.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise UserError(f"GA setting {name} must be an integer >= {low}, got {v!r}")
        for name in ("mutation_chance", "mutation_genes", "good_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                raise UserError(f"GA setting {name} must be in [0, 1], got {v!r}")
        for name in ("mutation_n", "fitness_floor", "stats_h", "stats_prior"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise UserError(f"GA setting {name} must be a finite number >= 0, got {v!r}")
        if not 0.0 < self.stats_h < 1.0:
            raise UserError(f"GA setting stats_h must be in (0, 1), got {self.stats_h!r}")
        if self.good_fraction == 0.0:
            raise UserError("GA setting good_fraction must be > 0")

    @property
    def n_leaves(self) -> int:
        return 2**self.depth

    @property
    def n_nodes(self) -> int:
        return 2 ** (self.depth + 1) - 1


TRACE_COLUMNS = ("eval", "node", "level", "generation", "loss", "best", "seconds")
"""Columns of :attr:`TreeGA.trace`, one row per evaluation."""

GA_PROFILES = {
    "paper": GASettings(),
    "default": GASettings(budget=2500, initial_population=64, max_population=50, stats_samples=1000,
                          mutation_candidates=5),
    "smoke": GASettings(budget=120, depth=1, initial_population=12, max_population=10,
                        mutation_candidates=20, bins=4, stats_samples=24),
}
"""Named GA settings.

- ``paper``: the authors' code configuration (``docs/design``, "Tree GA": populations
  125/100, 5000 evaluations; the paper's text gives 50 000 evaluations for trees) and the
  paper's 500 mutants per mutation; the values the paper does not give (depth, B, M_chance, M_genes, h,
  eps, sample size) are the field defaults of :class:`GASettings`.
- ``default``: 2500 evaluations, half the authors' configuration. On tree_1 / tree_2 (one view, seed 0) 5000
  lower the final loss from 0.541 / 0.481 to 0.506 / 0.382 but not the 64-view IoU (0.686 /
  0.796 with 2500, 0.681 / 0.798 with 5000): past ~2500 evaluations the search refines what
  one view shows. At 30-60 ms per tree evaluation a run takes 1.5-2.5 minutes on one core,
  which keeps the default DAG with six cases under 30 minutes. The statistics (1000 points =
  2000 evaluations) are a stage cached per generator and seed; one file serves every case. Smaller populations (64 initial, 50 max) give each of the 7
  GAs about 13 generations, as in ``paper``. 5 mutants instead of 500: the best of 500 by ``Q``
  pulls every mutation onto the marginally best bins. On tests/test_ga.py's mixed problem (600
  evaluations, median best loss over 9 seeds; GA without statistics 0.013, random search about
  0.28), with statistics from 600 / 1000 / 3000 points: 5 mutants 0.013 / 0.010 / 0.007,
  20 mutants 0.032 / 0.017 / 0.005, 500 mutants 0.067 / 0.024 / 0.027. Few mutants are the
  choice that does not hurt when the statistics are rough (a stochastic generator, few points).
- ``smoke``: 120 evaluations, a 3-node tree, for CI.
"""


def get_settings(name: str, **overrides) -> GASettings:
    """The named GA profile with ``overrides`` applied; ``UserError`` for unknown names or fields."""
    if name not in GA_PROFILES:
        raise UserError(f"unknown GA profile {name!r} (known: {', '.join(GA_PROFILES)})")
    known = {f.name for f in fields(GASettings)}
    bad = sorted(set(overrides) - known)
    if bad:
        raise UserError(f"unknown GA setting(s) {', '.join(bad)} (known: {', '.join(sorted(known))})")
    return replace(GA_PROFILES[name], **overrides)


# ----------------------------------------------------------------------------------------------
# Genes in the unit cube


def _levels(spec: ParamSpec) -> tuple[np.ndarray, np.ndarray]:
    """Lowest integer and number of integer values of each discrete gene (1 for continuous)."""
    lo = np.where(spec.discrete, np.ceil(spec.lower - 1e-9), 0.0)
    n = np.where(spec.discrete, np.floor(spec.upper + 1e-9) - lo + 1, 1.0)
    return lo, np.maximum(n, 1).astype(np.int64)


def snap(spec: ParamSpec, u: np.ndarray) -> np.ndarray:
    """Unit vectors ``u`` (..., N) with discrete genes moved onto their grid (what ``from_unit`` makes)."""
    u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
    grid = np.clip(spec.to_unit(spec.from_unit(u)), 0.0, 1.0)
    return np.where(spec.discrete, grid, u)


def random_genes(spec: ParamSpec, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` uniform random unit vectors; discrete genes uniform over their integer values."""
    lo, levels = _levels(spec)
    u = rng.random((n, len(spec)))
    k = np.floor(u * levels)  # a uniform level index per discrete gene
    span = np.where(spec.discrete, spec.upper - spec.lower, 1.0)
    disc = np.clip((lo + k - spec.lower) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    return np.where(spec.discrete, disc, u)


def crossover(a: np.ndarray, b: np.ndarray, cut: int) -> np.ndarray:
    """One-point crossover: genes ``[0, cut)`` from ``a``, ``[cut, N)`` from ``b``."""
    return np.concatenate([a[:cut], b[cut:]])


def genes_to_change(settings: GASettings, n_genes: int) -> int:
    """``n * M_genes`` of the paper as a count of genes: ``round(n * M_genes * N)``, in [1, N]."""
    return int(np.clip(round(settings.mutation_n * settings.mutation_genes * n_genes), 1, n_genes))


def mutate(spec: ParamSpec, g: np.ndarray, rng: np.random.Generator, n_change: int, weights: np.ndarray,
           candidates: int, quality: Callable[[np.ndarray], np.ndarray] | None) -> np.ndarray:
    """The paper's mutation of genome ``g`` (N,): ``candidates`` mutants, each with ``n_change``
    genes drawn without replacement with probability proportional to ``weights`` and set to new
    random values; the mutant with the largest ``quality`` is returned (the first without one)."""
    n = len(g)
    if quality is None:
        candidates = 1
    # weighted sampling without replacement, all candidates at once (Gumbel top-k)
    keys = np.log(np.maximum(weights, 1e-300)) + rng.gumbel(size=(candidates, n))
    chosen = np.argpartition(-keys, n_change - 1, axis=1)[:, :n_change]
    mask = np.zeros((candidates, n), bool)
    np.put_along_axis(mask, chosen, True, axis=1)
    mutants = np.where(mask, random_genes(spec, rng, candidates), g[None, :])
    if candidates == 1:
        return mutants[0]
    return mutants[int(np.argmax(quality(mutants)))]


# ----------------------------------------------------------------------------------------------
# Statistics: V(k), P_ij, P_0, Q_ij


@dataclass(frozen=True)
class GeneStatistics:
    """Per-gene statistics of a generator's losses on random samples (the paper's V, P, Q)."""

    names: tuple[str, ...]
    """Gene names, in vector order (must match the spec they are used with)."""
    counts: np.ndarray
    """Samples whose gene ``i`` fell in bin ``j``, shape (N, B) (summed over the family)."""
    good: np.ndarray
    """Good samples among them, shape (N, B)."""
    v: np.ndarray
    """``V(k)``: mean absolute rate of change of the loss along gene ``k`` (unit cube), shape (N,)."""
    epsilon: np.ndarray
    """Loss threshold of "good" per objective of the family, shape (F,)."""
    n_samples: int
    """Random points drawn (each evaluated at ``x`` and ``x + h e_k``)."""
    h: float
    """Finite-difference step used for ``V``."""
    good_fraction: float
    """Quantile of each objective's losses used as its ``epsilon``."""
    prior: float
    """Pseudo-samples at ``P_0`` added to each bin."""

    FORMAT = "ipm-ga-statistics"
    VERSION = 1

    @property
    def bins(self) -> int:
        return self.counts.shape[1]

    @property
    def p0(self) -> float:
        """``P_0 = P(good)`` over all samples (each gene's bins count every sample once)."""
        total = self.counts[0].sum()
        return float(self.good[0].sum() / total) if total else 0.0

    @property
    def p(self) -> np.ndarray:
        """``P_ij = P(good | x_i in bin j)``, shape (N, B), shrunk towards ``P_0`` by ``prior``."""
        return (self.good + self.prior * self.p0) / np.maximum(self.counts + self.prior, 1e-12)

    @property
    def q(self) -> np.ndarray:
        """``Q_ij = sign(P_ij - P_0) * max(P_ij, P_0) / min(P_ij, P_0)``, shape (N, B)."""
        p, p0 = self.p, self.p0
        if p0 <= 0.0:
            return np.zeros_like(p)
        ratio = np.maximum(p, p0) / np.maximum(np.minimum(p, p0), 1e-12)
        return np.sign(p - p0) * ratio

    def quality(self, genomes: np.ndarray) -> np.ndarray:
        """``Q(G) = sum_i Q(i, floor(G_i * B))`` for genomes (..., N) in the unit cube."""
        g = np.asarray(genomes, np.float64)
        j = np.clip(np.floor(g * self.bins), 0, self.bins - 1).astype(np.int64)
        q = self.q
        return q[np.arange(q.shape[0]), j].sum(axis=-1)

    def mutation_weights(self) -> np.ndarray:
        """Probabilities of the genes to be mutated: proportional to ``V(k)``, plus 1 % of the
        mean so that a gene whose samples never moved the loss can still change."""
        w = self.v + 0.01 * max(float(self.v.mean()), 1e-12)
        return w / w.sum()

    def check(self, spec: ParamSpec) -> None:
        """``UserError`` unless these statistics were collected for ``spec``'s genes."""
        if tuple(spec.names) != self.names:
            raise UserError(f"GA statistics are for genes {list(self.names)[:4]}... ({len(self.names)}), "
                            f"not for this generator's {list(spec.names)[:4]}... ({len(spec.names)})")

    def to_dict(self) -> dict:
        return {"format": self.FORMAT, "version": self.VERSION, "names": list(self.names),
                "counts": self.counts.tolist(), "good": self.good.tolist(), "v": self.v.tolist(),
                "epsilon": self.epsilon.tolist(), "n_samples": self.n_samples, "h": self.h,
                "good_fraction": self.good_fraction, "prior": self.prior}

    def save(self, path: str | Path) -> None:
        """Write as JSON, atomically."""
        from ipm.io.atomic import atomic_path

        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict()) + "\n")

    @classmethod
    def from_dict(cls, d: dict, source: str = "GA statistics") -> GeneStatistics:
        """Validate and build; ``UserError`` naming the problem otherwise."""

        def bad(why: str) -> UserError:
            return UserError(f"{source}: {why}")

        if not isinstance(d, dict) or d.get("format") != cls.FORMAT:
            raise bad(f"not an {cls.FORMAT} file")
        if d.get("version") != cls.VERSION:
            raise bad(f"unsupported version {d.get('version')!r} (expected {cls.VERSION})")
        missing = [k for k in ("names", "counts", "good", "v", "epsilon", "n_samples", "h", "good_fraction",
                               "prior") if k not in d]
        if missing:
            raise bad(f"missing {', '.join(missing)}")
        names = d["names"]
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise bad("names must be a non-empty list of strings")
        try:
            counts = np.asarray(d["counts"], np.float64)
            good = np.asarray(d["good"], np.float64)
            v = np.asarray(d["v"], np.float64)
            eps = np.asarray(d["epsilon"], np.float64)
            n_samples, h, frac, prior = int(d["n_samples"]), float(d["h"]), float(d["good_fraction"]), float(d["prior"])
        except (TypeError, ValueError) as e:
            raise bad(f"malformed numbers ({e})") from None
        n = len(names)
        if counts.ndim != 2 or counts.shape[0] != n or counts.shape[1] < 1 or good.shape != counts.shape:
            raise bad(f"counts and good must both have shape ({n}, B), got {counts.shape} and {good.shape}")
        if v.shape != (n,):
            raise bad(f"v must have shape ({n},), got {v.shape}")
        if eps.ndim != 1:
            raise bad("epsilon must be a list")
        arrays = {"counts": counts, "good": good, "v": v, "epsilon": eps}
        for key, arr in arrays.items():
            if not np.all(np.isfinite(arr)):
                raise bad(f"{key} has non-finite values")
        if np.any(counts < 0) or np.any(good < 0) or np.any(good > counts) or np.any(v < 0):
            raise bad("counts, good and v must be >= 0, with good <= counts")
        if np.any(counts != np.round(counts)) or np.any(good != np.round(good)):
            raise bad("counts and good must be integers")
        if not np.all(counts.sum(axis=1) == counts[0].sum()) or not np.all(good.sum(axis=1) == good[0].sum()):
            raise bad("every gene's bins must count the same samples")
        if not (n_samples >= 1 and 0 < h < 1 and 0 < frac <= 1 and prior >= 0 and math.isfinite(prior)):
            raise bad("n_samples, h, good_fraction or prior out of range")
        return cls(tuple(names), counts.astype(np.int64), good.astype(np.int64), v, eps, n_samples, h, frac, prior)

    @classmethod
    def load(cls, path: str | Path) -> GeneStatistics:
        """Read a file written by :meth:`save`; ``UserError`` if it is missing or malformed."""
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise UserError(f"GA statistics file not found: {path}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise UserError(f"GA statistics file {path} is not valid JSON ({e})") from None
        return cls.from_dict(d, source=f"GA statistics file {path}")


def collect_statistics(spec: ParamSpec, evaluate: Callable[[np.ndarray], float | np.ndarray], n_samples: int,
                       bins: int, seed: int = 0, progress: bool = False, h: float = 0.05,
                       good_fraction: float = 0.1, prior: float = 2.0) -> GeneStatistics:
    """The paper's statistics from ``n_samples`` random points of the unit cube.

    ``evaluate(u) -> loss`` maps a unit vector (N,) to the loss of that sample; to gather the
    statistics over a *family* of objectives (the paper's ``F``: one per reference image), it
    returns a vector of losses (F,), one per objective. Non-finite losses count as bad and are
    left out of ``V``.

    Each point ``x`` is evaluated twice: at ``x`` and at ``x + h e_k`` for one gene ``k`` (the
    genes taken in turn, so each gets ``n_samples / N`` differences); the step goes down where
    up would leave the cube, and a discrete gene moves by ``max(h, one level)`` rounded to its
    grid. ``V(k)`` is the mean of ``|f(x + h e_k) - f(x)| / step`` over its differences and the
    family. Both points enter ``P_ij`` (the second differs from a uniform sample only in gene
    ``k`` near the cube's faces). Costs ``2 n_samples`` evaluations.
    """
    from tqdm import tqdm

    if n_samples < 1 or bins < 1:
        raise UserError(f"statistics need n_samples >= 1 and bins >= 1, got {n_samples} and {bins}")
    rng = np.random.default_rng(seed)
    n = len(spec)
    span = np.where(spec.discrete, spec.upper - spec.lower, 1.0)
    level = np.where(spec.discrete & (span > 0), 1.0 / np.where(span > 0, span, 1.0), 0.0)
    points = random_genes(spec, rng, n_samples)
    order = np.concatenate([rng.permutation(n) for _ in range(-(-n_samples // n))])[:n_samples]
    all_u, all_loss = [], []
    diffs = [[] for _ in range(n)]
    n_obj = None
    for s in tqdm(range(n_samples), desc="GA statistics", unit="sample", disable=not progress, leave=False):
        x, k = points[s], order[s]
        step = max(h, level[k])
        if spec.discrete[k] and level[k] > 0:
            step = max(round(step / level[k]), 1) * level[k]
        x2 = x.copy()
        x2[k] = x[k] + step if x[k] + step <= 1.0 + 1e-12 else x[k] - step
        x2 = snap(spec, x2)
        moved = abs(x2[k] - x[k])
        pair = []
        for u in (x, x2):
            loss = np.atleast_1d(np.asarray(evaluate(u.copy()), np.float64)).ravel()
            if n_obj is None:
                n_obj = len(loss)
            if len(loss) != n_obj or n_obj == 0:
                raise ValueError(f"evaluate returned {len(loss)} losses, expected {n_obj}")
            pair.append(loss)
            all_u.append(u)
            all_loss.append(loss)
        if moved > 0:
            d = np.abs(pair[1] - pair[0]) / moved
            diffs[k].extend(d[np.isfinite(d)].tolist())
    u = np.array(all_u)
    losses = np.array(all_loss)  # (2 n_samples, F)
    finite = np.isfinite(losses)
    eps = np.array([np.quantile(losses[finite[:, f], f], good_fraction) if finite[:, f].any() else -np.inf
                    for f in range(n_obj)])
    good = (finite & (losses <= eps[None, :])).sum(axis=1)  # good objectives per sample
    j = np.clip(np.floor(u * bins), 0, bins - 1).astype(np.int64)  # (S, N)
    counts = np.zeros((n, bins), np.int64)
    good_counts = np.zeros((n, bins), np.int64)
    for i in range(n):
        counts[i] = np.bincount(j[:, i], minlength=bins) * n_obj
        good_counts[i] = np.bincount(j[:, i], weights=good, minlength=bins).astype(np.int64)
    v = np.array([np.mean(dk) if dk else 0.0 for dk in diffs])
    return GeneStatistics(tuple(spec.names), counts, good_counts, v, eps, int(n_samples), float(h),
                          float(good_fraction), float(prior))


# ----------------------------------------------------------------------------------------------
# Elementary GA


def selection_probabilities(losses: np.ndarray, floor: float) -> np.ndarray:
    """Fitness-proportionate selection: fitness = loss rescaled over ``losses`` (best 1, worst 0)
    plus ``floor``; non-finite losses get the worst finite loss."""
    losses = np.asarray(losses, np.float64)
    finite = np.isfinite(losses)
    if not finite.any():
        return np.full(len(losses), 1.0 / len(losses))
    lo, hi = losses[finite].min(), losses[finite].max()
    losses = np.where(finite, losses, hi)
    fit = (hi - losses) / (hi - lo) if hi > lo else np.ones(len(losses))
    fit = fit + floor
    if fit.sum() <= 0:
        return np.full(len(losses), 1.0 / len(losses))
    return fit / fit.sum()


class ElementaryGA:
    """One elementary GA of the paper, ask/tell: ``ask()`` unit vectors, ``tell(losses)``.

    Starts from ``initial_population`` random individuals (a leaf) or from an evaluated
    ``initial`` population with ``initial_losses`` (a higher node of the tree). ``budget`` caps
    its evaluations (``None``: no cap); the last generation may be partial.
    """

    def __init__(self, spec: ParamSpec, settings: GASettings, stats: GeneStatistics | None = None,
                 seed: int | np.random.Generator | None = 0, budget: int | None = None,
                 initial: np.ndarray | None = None, initial_losses: np.ndarray | None = None):
        if stats is not None:
            stats.check(spec)
        self.spec, self.settings, self.stats = spec, settings, stats
        self.rng = np.random.default_rng(seed)
        self.budget = budget
        self.evaluations = 0
        self.generation = 0
        """Index of the generation being (or last) evaluated; 0 is the initial population."""
        self.n_change = genes_to_change(settings, len(spec))
        self.weights = stats.mutation_weights() if stats is not None else np.full(len(spec), 1.0 / len(spec))
        self._quality = stats.quality if stats is not None else None
        self._pending: np.ndarray | None = None
        self._survivors = np.empty((0, len(spec)))
        self._survivor_losses = np.empty(0)
        if initial is None:
            self.pop, self.losses = np.empty((0, len(spec))), np.empty(0)
        else:
            initial = snap(spec, np.atleast_2d(np.asarray(initial, np.float64)))
            initial_losses = _clean_losses(initial_losses, len(initial))
            order = np.argsort(initial_losses, kind="stable")
            self.pop, self.losses = initial[order], initial_losses[order]
        self.initial = self.pop.copy()
        """The population the GA started from (empty for a leaf before its first ``ask``)."""

    @property
    def remaining(self) -> float:
        return math.inf if self.budget is None else self.budget - self.evaluations

    @property
    def done(self) -> bool:
        return self.remaining <= 0 and self._pending is None

    @property
    def best_u(self) -> np.ndarray:
        return self.pop[0].copy()

    @property
    def best_loss(self) -> float:
        return float(self.losses[0]) if len(self.losses) else math.inf

    def best(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` best individuals and their losses (the population is kept sorted)."""
        return self.pop[:k].copy(), self.losses[:k].copy()

    def ask(self) -> np.ndarray:
        """The next batch of unit vectors to evaluate, shape (n, N)."""
        if self._pending is not None:
            raise RuntimeError("ask() called twice without tell()")
        if self.remaining <= 0:
            raise RuntimeError("the GA's evaluation budget is spent")
        s = self.settings
        if len(self.pop) == 0:  # a leaf's random initial population
            n = int(min(s.initial_population, self.remaining))
            batch = random_genes(self.spec, self.rng, n)
            self._survivors, self._survivor_losses = batch[:0], np.empty(0)
        else:
            self.generation += 1
            keep = max(1, min(math.ceil(len(self.pop) / 2), s.max_population - 1))
            self._survivors, self._survivor_losses = self.pop[:keep], self.losses[:keep]
            n = int(min(s.max_population - keep, self.remaining))
            batch = self._children(n)
        self.initial = self.initial if len(self.initial) else batch.copy()
        self._pending = batch
        return batch.copy()

    def _children(self, n: int) -> np.ndarray:
        """``n`` children of the survivors: crossover of fitness-proportionate parents, then mutation."""
        s, parents = self.settings, self._survivors
        probs = selection_probabilities(self._survivor_losses, s.fitness_floor)
        out = []
        seen = {p.tobytes() for p in parents}
        n_genes = len(self.spec)
        for _ in range(n):
            a = self.rng.choice(len(parents), p=probs)
            if len(parents) > 1:
                rest = probs.copy()
                rest[a] = 0.0
                b = self.rng.choice(len(parents), p=rest / rest.sum())
            else:
                b = a
            cut = int(self.rng.integers(1, n_genes)) if n_genes > 1 else 1
            child = crossover(parents[a], parents[b], cut)
            # a child that copies an individual would waste an evaluation: it is always mutated
            if self.rng.random() < s.mutation_chance or child.tobytes() in seen:
                child = mutate(self.spec, child, self.rng, self.n_change, self.weights, s.mutation_candidates,
                               self._quality)
            child = snap(self.spec, child)
            seen.add(child.tobytes())
            out.append(child)
        return np.array(out).reshape(n, n_genes)

    def tell(self, losses) -> None:
        """Losses of the last ``ask()`` batch (NaN counts as the worst)."""
        if self._pending is None:
            raise RuntimeError("tell() called without a pending ask()")
        losses = _clean_losses(losses, len(self._pending))
        self.evaluations += len(self._pending)
        pop = np.concatenate([self._survivors, self._pending])
        loss = np.concatenate([self._survivor_losses, losses])
        order = np.argsort(loss, kind="stable")
        self.pop, self.losses = pop[order], loss[order]
        self._pending = None


def _clean_losses(losses, n: int) -> np.ndarray:
    """A float vector of length ``n`` with NaN replaced by +inf; ``ValueError`` on a wrong length."""
    arr = np.asarray(losses, np.float64).ravel() if losses is not None else np.empty(0)
    if arr.shape != (n,):
        raise ValueError(f"expected {n} losses, got {arr.size}")
    return np.where(np.isnan(arr), np.inf, arr)


# ----------------------------------------------------------------------------------------------
# Tree of elementary GAs


@dataclass
class Node:
    """One elementary GA of the tree: its place, its budget and (once started) the GA."""

    index: int
    """Position in execution order (post-order: children before parents; the root is last)."""
    level: int
    """0 for leaves, ``depth`` for the root."""
    children: tuple[int, ...]
    """Indices of the two child nodes (empty for leaves)."""
    budget: int
    """Evaluations this GA may spend."""
    ga: ElementaryGA | None = None


def plan_tree(settings: GASettings, budget: int) -> list[Node]:
    """Nodes in post-order with their budgets: the leaves' initial populations first, the rest
    split equally over all nodes, the remainder to the root. ``UserError`` if ``budget`` does not
    cover the leaves' initial populations."""
    leaves, n_nodes = settings.n_leaves, settings.n_nodes
    rest = budget - leaves * settings.initial_population
    if rest < 0:
        raise UserError(f"GA budget {budget} is below the {leaves} leaves' initial populations "
                        f"({leaves} x {settings.initial_population}); lower depth or initial_population")
    share, extra = divmod(rest, n_nodes)
    nodes: list[Node] = []

    def build(level: int) -> int:
        kids = () if level == 0 else (build(level - 1), build(level - 1))
        own = share + (settings.initial_population if level == 0 else 0)
        nodes.append(Node(len(nodes), level, kids, own))
        return len(nodes) - 1

    build(settings.depth)
    nodes[-1].budget += extra
    return nodes


@ALGORITHMS.register("ga")
class TreeGA:
    """The paper's tree of elementary GAs, ask/tell at the top level.

    ``ask()`` returns the next batch (one generation of the current node), ``tell(losses)``
    records it; nodes run in post-order, each higher node starting from the best
    ``ceil(max_population / 2)`` of each child's final population. ``trace`` has one row per
    evaluation: ``eval, node, level, generation, loss, best``.
    """

    def __init__(self, spec: ParamSpec, settings: GASettings, stats: GeneStatistics | None = None,
                 seed: int = 0, budget: int | None = None):
        if stats is not None:
            stats.check(spec)
        self.spec, self.settings, self.stats, self.seed = spec, settings, stats, seed
        self._plan(settings.budget if budget is None else budget)

    def _plan(self, budget: int) -> None:
        self.budget = int(budget)
        self.nodes = plan_tree(self.settings, self.budget)
        seeds = np.random.SeedSequence(self.seed).spawn(len(self.nodes))
        self._rngs = [np.random.default_rng(s) for s in seeds]
        self._current = 0
        self._pending: np.ndarray | None = None
        self._rows: list[tuple] = []
        self._t0 = time.perf_counter()
        self.evaluations = 0
        self.best_u: np.ndarray | None = None
        self.best_loss = math.inf

    def _start(self, node: Node) -> ElementaryGA:
        if node.ga is None:
            if node.children:
                half = math.ceil(self.settings.max_population / 2)
                parts = [self.nodes[c].ga.best(half) for c in node.children]
                initial = np.concatenate([p[0] for p in parts])
                losses = np.concatenate([p[1] for p in parts])
                node.ga = ElementaryGA(self.spec, self.settings, self.stats, self._rngs[node.index], node.budget,
                                       initial, losses)
            else:
                node.ga = ElementaryGA(self.spec, self.settings, self.stats, self._rngs[node.index], node.budget)
        return node.ga

    @property
    def done(self) -> bool:
        return self._pending is None and self.evaluations >= self.budget

    @property
    def root(self) -> Node:
        return self.nodes[-1]

    def ask(self) -> np.ndarray:
        """The next batch of unit vectors to evaluate, shape (n, N)."""
        if self._pending is not None:
            raise RuntimeError("ask() called twice without tell()")
        if self.done:
            raise RuntimeError("the GA's evaluation budget is spent")
        while True:
            node = self.nodes[self._current]
            ga = self._start(node)
            if not ga.done:
                break
            self._current += 1  # a node whose budget is spent (or zero): move up the tree
        self._pending = ga.ask()
        return self._pending.copy()

    def tell(self, losses) -> None:
        """Losses of the last ``ask()`` batch, in order (NaN counts as the worst)."""
        if self._pending is None:
            raise RuntimeError("tell() called without a pending ask()")
        losses = _clean_losses(losses, len(self._pending))
        node = self.nodes[self._current]
        node.ga.tell(losses)
        now = time.perf_counter() - self._t0
        for u, loss in zip(self._pending, losses):
            if loss < self.best_loss or self.best_u is None:
                self.best_loss, self.best_u = float(loss), u.copy()
            self._rows.append((self.evaluations, node.index, node.level, node.ga.generation, float(loss),
                               self.best_loss, now))
            self.evaluations += 1
        self._pending = None

    @property
    def trace(self) -> pd.DataFrame:
        """One row per evaluation: eval, node, level, generation, loss, best (so far), seconds (since
        the plan, when its batch was told)."""
        import pandas as pd

        return pd.DataFrame(self._rows, columns=TRACE_COLUMNS)

    def minimize(self, loss_fn: Callable[[np.ndarray], float], budget: int | None = None, progress: bool = True,
                 on_eval: Callable[[dict, np.ndarray], None] | None = None) -> tuple[np.ndarray, float, pd.DataFrame]:
        """Drive ask/tell with ``loss_fn(u) -> loss`` until the budget is spent.

        ``budget`` (default: the settings') re-plans the tree if nothing was asked yet.
        ``on_eval(row, u)`` is called for each evaluation, in order, once its batch is told, with
        its trace row (a dict) and its unit vector.
        Returns the best unit vector, its loss and the trace.
        """
        from tqdm import tqdm

        if budget is not None and budget != self.budget:
            if self.evaluations or self._pending is not None:
                raise RuntimeError("the budget can only change before the first ask()")
            self._plan(budget)
        bar = tqdm(total=self.budget, desc="GA", unit="eval", disable=not progress, leave=False)
        try:
            while not self.done:
                batch = self.ask()
                losses = []
                for u in batch:
                    losses.append(float(loss_fn(u.copy())))
                    bar.update(1)
                n0 = len(self._rows)
                self.tell(losses)
                if on_eval is not None:
                    for row, u in zip(self._rows[n0:], batch):
                        on_eval(dict(zip(TRACE_COLUMNS, row)), u.copy())
                bar.set_postfix(node=self._current, best=f"{self.best_loss:.5f}")
        finally:
            bar.close()
        return self.best_u.copy(), self.best_loss, self.trace
