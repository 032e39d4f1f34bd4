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

``V(k)`` and ``Q`` are the gene statistics of ``ipm.optim.ga_statistics``.

**Tree of GAs** (:class:`TreeGA`): a complete binary tree of ``2**depth`` leaves; leaves start
from random populations of ``initial_population``, every higher node from the best halves of
its two children's final populations (already evaluated), and the root's best is the answer.
The paper gives each elementary GA "a fixed number of generations"; so after the leaves'
initial populations the evaluation budget is split equally over all nodes (the rounding
remainder goes to the root).

Choices the paper leaves open are fields of ``ipm.optim.ga_settings.GASettings`` with their reasons.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from ipm.errors import UserError
from ipm.optim.registry import ALGORITHMS
from ipm.optim.ga_settings import GASettings
from ipm.optim.ga_statistics import GeneStatistics, random_genes, snap

if TYPE_CHECKING:
    import pandas as pd

    from ipm.generators.base import ParamSpec


TRACE_COLUMNS = ("eval", "node", "level", "generation", "loss", "best", "seconds")
"""Columns of :attr:`TreeGA.trace`, one row per evaluation."""


# ----------------------------------------------------------------------------------------------
# Genetic operators


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
