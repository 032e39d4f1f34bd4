"""The paper's memetic algorithm: a GA over presets and discrete parameters with Adam inside.

Per generation (``docs/design``, "Memetic search"; the authors' settings are
the ``paper`` profile, ``ipm.profiles``):
1. Adam local search; the generation's steps are shared by quality
   ``q = (1 / (0.001 + err)) ** (1 + 0.2 it) * exp(-0.005 stall)`` (``stall``: steps since the
   individual last improved by 1 %); a step whose loss exceeds ``reject_ratio`` times the
   individual's best is undone and its rate halved (relative to the best, not the last loss,
   so accepted small rises cannot ratchet the loss upwards); each individual keeps its best point;
2. individuals in the same initialisation bin (topology key and yaw bin; one yaw bin per key for
   an object that looks the same turned,
   whose yaw bins would hold turned twins of one basin) are merged (best kept);
3. the worst ``remove_share`` are removed; the population is refilled with children of
   fitness-proportionate parents: a one-point crossover of the shape genes (pose from the
   first parent), then each gene mutated with probability ``mutate_share / 10``, each discrete
   gene moved with probability ``mutate_share / 5`` (:func:`move_discrete`: a two-valued gene
   flips, a many-valued one steps to a neighbouring value or draws another), the yaw jumping to
   a random bin with probability ``mutate_share``.
``evaluate(z) -> (loss, grad)`` is the only link to rendering, so the algorithm is testable alone.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Annotated, Callable

import numpy as np

from ipm.lanes import Lanes, Task
from ipm.optim.adam import AdamState, adam_init, adam_update
from ipm.settings import UNIT, Range, Settings, at_least


@dataclass(frozen=True)
class MemeticSettings(Settings):
    """Settings of the memetic stage and of every Adam run of the differentiable path."""

    KIND = "diff setting"
    population: Annotated[int, at_least(1)] = 16
    """Individuals in the memetic population (initialised from presets and random samples)."""
    ga_iterations: Annotated[int, at_least(1)] = 20
    """Generations of the memetic algorithm."""
    adam_per_iteration: Annotated[int, at_least(0)] = 160
    """Adam steps per generation, shared among individuals by quality."""
    remove_share: Annotated[float, UNIT] = 0.2
    """Share of the worst individuals removed each generation."""
    mutate_share: Annotated[float, UNIT] = 0.5
    """Share of the population replaced by mutants of good individuals each generation."""
    random_share: Annotated[float, UNIT] = 0.25
    """Share of the initial population drawn at random instead of from presets."""
    yaw_bins: Annotated[int, at_least(1)] = 16
    """Initialisation bins of the yaw angle; individuals in the same bin are merged (one bin for an object that
    looks the same turned: docs/decisions.md, 'One yaw bin for turned look-alikes')."""
    lr: Annotated[float, Range(0.0, open_lo=True)] = 0.05
    """Adam learning rate (unit-cube parameters; radians; object sizes)."""
    reject_ratio: Annotated[float, Range(1.0)] = 1.2
    """A step that raises the loss by more than this factor is undone and the rate halved."""
    memetic_res: Annotated[int, at_least(8)] = 128
    """Render width of the memetic stage (pixels)."""
    memetic_lod: Annotated[int, at_least(0)] = 0
    """Generator level of detail in the memetic stage."""


@dataclass
class Individual:
    """One candidate: its vector, topology key, loss/gradient there, and its Adam state."""

    z: np.ndarray
    key: tuple
    origin: str
    loss: float = np.inf
    grad: np.ndarray | None = None
    lr: float = 0.05
    adam: AdamState | None = None
    stall: int = 0
    best_loss: float = np.inf
    best_z: np.ndarray | None = None

    def remember(self) -> None:
        """Record the current point if it is the best this individual has seen."""
        if self.loss < self.best_loss:
            if self.loss < 0.99 * self.best_loss:
                self.stall = 0
            self.best_loss, self.best_z = self.loss, self.z.copy()


def log_quality(losses: np.ndarray, stalls: np.ndarray, it: int) -> np.ndarray:
    """log q of the budget-sharing rule (logs avoid overflow of the growing exponent)."""
    return -(1.0 + 0.2 * it) * np.log(0.001 + losses) - 0.005 * stalls


def share_budget(budget: int, logq: np.ndarray) -> np.ndarray:
    """Split ``budget`` steps proportionally to q (largest remainders first)."""
    q = np.exp(logq - logq.max())
    raw = budget * q / q.sum()
    n = np.floor(raw).astype(int)
    for i in np.argsort(-(raw - n))[: budget - n.sum()]:
        n[i] += 1
    return n


def step_evaluations(n: int, fresh: bool) -> int:
    """The evaluations :func:`adam_steps` spends on ``n`` steps: one each, and one for the starting
    point of an individual never evaluated (``fresh``), even when ``n`` is 0."""
    return max(n, 1 if fresh else 0)


def adam_steps(ind: Individual, n: int, evaluate: Callable, clip: Callable, reject_ratio: float,
               on_eval: Callable) -> None:
    """``n`` Adam steps on ``ind`` with step rejection (:func:`step_evaluations` evaluations: an
    individual never evaluated spends its first on its starting point)."""
    for _ in range(step_evaluations(n, ind.grad is None)):
        z, state = _propose(ind, clip)
        loss, grad = evaluate(z)
        _accept(ind, z, state, loss, grad, reject_ratio)
        on_eval(ind)


def _propose(ind: Individual, clip: Callable):
    """The next point to evaluate for ``ind`` and the Adam state that goes with it: its starting
    point (state None) if it was never evaluated, else one Adam step on."""
    if ind.grad is None:
        return ind.z, None
    if ind.adam is None:
        ind.adam = adam_init(ind.z)
    step, state = adam_update(ind.adam, ind.grad, ind.lr)
    return clip(ind.z + step), state


def _accept(ind: Individual, z: np.ndarray, state, loss: float, grad: np.ndarray, reject_ratio: float) -> None:
    """Take the evaluation of a :func:`_propose` point: a starting point always; a step unless its
    loss is not finite or exceeds ``reject_ratio`` times the best (then the rate is halved)."""
    if state is None:
        ind.loss, ind.grad = loss, grad
        ind.remember()
        return
    ind.stall += 1
    if not np.isfinite(loss) or loss > reject_ratio * ind.best_loss:
        ind.lr *= 0.5
    else:
        ind.z, ind.loss, ind.grad, ind.adam = z, loss, grad, state
        ind.remember()


def yaw_bin(z: np.ndarray, n_shape: int, bins: int) -> int:
    return int(np.floor(np.mod(z[n_shape], 2 * np.pi) / (2 * np.pi) * bins)) % bins


def merge_bins(pop: list[Individual], n_shape: int, bins: int,
               yaw_free: Callable = lambda z: False) -> list[Individual]:
    """Keep the best individual of each (topology key, yaw bin); an object that looks
    the same turned (``yaw_free(z)``) has one yaw bin: its turned twins are one individual, not many."""
    best: dict = {}
    for ind in pop:
        k = (ind.key, 0 if yaw_free(ind.z) else yaw_bin(ind.z, n_shape, bins))
        if k not in best or ind.best_loss < best[k].best_loss:
            best[k] = ind
    return sorted(best.values(), key=lambda i: i.best_loss)


def move_discrete(u: np.ndarray, levels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """New unit-cube values for discrete genes at ``u`` with ``levels`` values each: a two-valued
    gene flips (no random draw, so two-valued searches keep their random stream); a many-valued
    one steps by one value up or down (reflected at the ends) or, as often, draws another value."""
    k = np.round(u * (levels - 1)).astype(int)
    out = (1 - k).astype(float)
    for i in np.nonzero(levels > 2)[0]:
        n = int(levels[i])
        if rng.random() < 0.5:
            step = 1 if k[i] == 0 else -1 if k[i] == n - 1 else int(rng.choice((-1, 1)))
            new = k[i] + step
        else:
            new = int(rng.choice([v for v in range(n) if v != k[i]]))
        out[i] = new / (n - 1)
    return out


def make_child(parents: list[Individual], probs: np.ndarray, rng: np.random.Generator, n_shape: int,
               profile: MemeticSettings, levels: np.ndarray, key_of: Callable, clip: Callable) -> Individual:
    """Crossover (one point over the shape genes) and mutation of fitness-proportionate parents;
    ``levels``: values per shape gene (0: continuous)."""
    a, b = rng.choice(len(parents), size=2, p=probs)
    z = parents[a].best_z.copy()
    cut = rng.integers(1, n_shape)
    z[cut:n_shape] = parents[b].best_z[cut:n_shape]
    genes = rng.random(n_shape) < profile.mutate_share / 10
    z[:n_shape] = np.where(genes, z[:n_shape] + rng.normal(0.0, 0.15, n_shape), z[:n_shape])
    flip = (levels[:n_shape] > 0) & (rng.random(n_shape) < profile.mutate_share / 5)
    if flip.any():
        z[:n_shape][flip] = move_discrete(z[:n_shape][flip], levels[:n_shape][flip], rng)
    if rng.random() < profile.mutate_share:
        z[n_shape] = (rng.integers(profile.yaw_bins) + 0.5) / profile.yaw_bins * 2 * np.pi
    z = clip(z)
    return Individual(z, key_of(z), "child", lr=profile.lr)


def memetic(initial: list[Individual], evaluate: Callable, clip: Callable, key_of: Callable,
            n_shape: int, levels: np.ndarray, profile: MemeticSettings, rng: np.random.Generator,
            on_eval: Callable = lambda ind: None, prepare: Callable = lambda z: z,
            yaw_free: Callable = lambda z: False, side: Lanes | None = None) -> list[Individual]:
    """Run the memetic stage from ``initial``; the last generation, best first (one individual
    per topology key and yaw bin): the first one's ``best_z`` is the answer.

    ``prepare(z)`` adjusts each child before its first evaluation (the differentiable path
    rescales it to the targets' silhouette area, as it does for the initial population);
    ``yaw_free(z)``: the object ``z`` looks the same turned (:func:`merge_bins`); ``side``: where
    the individuals' steps run (side by side on its threads, with the results of one after another).
    """
    side = side or Lanes()

    def steps(inds: list[Individual], ns) -> list[Individual]:
        def task(ind: Individual, n: int) -> Task:
            def run() -> Individual:
                mine = copy.deepcopy(ind)  # the given one stays as it was, should the try run again
                adam_steps(mine, n, evaluate, clip, profile.reject_ratio, on_eval)
                return mine
            return Task(run, {evaluate: step_evaluations(n, ind.grad is None)})

        return side.map([task(ind, n) for ind, n in zip(inds, ns)])

    pop = list(initial)
    for it in range(profile.ga_iterations):
        fresh = [k for k, ind in enumerate(pop) if ind.grad is None]
        for k, ind in zip(fresh, steps([pop[k] for k in fresh], [1] * len(fresh))):
            pop[k] = ind
        losses = np.array([i.best_loss for i in pop])
        stalls = np.array([i.stall for i in pop])
        pop = steps(pop, share_budget(profile.adam_per_iteration, log_quality(losses, stalls, it)))
        for ind in pop:
            ind.key = key_of(ind.z)
        pop = merge_bins(pop, n_shape, profile.yaw_bins, yaw_free)
        if it == profile.ga_iterations - 1:
            break
        keep = max(1, len(pop) - int(np.ceil(profile.remove_share * profile.population)))
        pop = pop[:keep]
        logq = log_quality(np.array([i.best_loss for i in pop]), np.array([i.stall for i in pop]), it)
        probs = np.exp(logq - logq.max())
        probs /= probs.sum()
        while len(pop) < profile.population:
            child = make_child(pop[:keep], probs, rng, n_shape, profile, levels, key_of, clip)
            child.z = prepare(child.z)
            child.key = key_of(child.z)
            pop.append(child)
    return pop
