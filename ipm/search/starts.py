"""Where the search starts: the memetic stage's first population (a pluggable part of the loop).

A start is a callable ``(problem, settings, rng, prepare) -> list[Individual]`` (``settings``:
``ipm.optim.memetic.MemeticSettings``; ``prepare`` adjusts each start, e.g. its scale). Today's
are :func:`preset_start` and :func:`learned_start` (the regressor's proposals first, ``ipm.learned``);
:func:`start_for` picks one for a fit; the loop takes either unchanged.
"""
from __future__ import annotations

import numpy as np

from ipm.optim.memetic import Individual, MemeticSettings
from ipm.problem import Problem


def preset_start(problem: Problem, settings: MemeticSettings, rng: np.random.Generator,
                 prepare=lambda z: z) -> list[Individual]:
    """The generator's presets and random samples (``random_share`` of them), spread over yaw bins
    and, for an unknown camera, over its pitch (``UnknownCamera.spread``)."""
    presets = list(problem.generator.presets.items())
    n_random = int(round(settings.random_share * settings.population))
    bins = rng.permutation(np.resize(np.arange(settings.yaw_bins), max(settings.population, settings.yaw_bins)))
    cameras = [None] * settings.population
    if problem.camera is not None:
        cameras = problem.camera.spread(settings.population, rng)
    pop = []
    for i in range(settings.population):
        yaw = (bins[i] + rng.random()) / settings.yaw_bins * 2 * np.pi
        if i < settings.population - n_random:
            name, x = presets[i % len(presets)]
            u = problem.spec.to_unit(x)
        else:
            name, u = "random", rng.random(problem.n_shape)
        z = prepare(problem.initial_z(u, yaw, cameras[i]))
        pop.append(Individual(z, problem.key(z), name, lr=settings.lr))
    return pop


def proposed_start(problem: Problem, settings: MemeticSettings, rng: np.random.Generator, prepare,
                   proposals: list[np.ndarray], origin: str) -> list[Individual]:
    """A population whose first individuals are ``proposals`` (at most the population, each
    ``prepare``d, named ``origin``), the rest :func:`preset_start`'s."""
    pop = []
    for z in proposals[: settings.population]:
        z = prepare(z)
        pop.append(Individual(z, problem.key(z), origin, lr=settings.lr))
    return pop + preset_start(problem, settings, rng, prepare)[: settings.population - len(pop)]


def learned_start(views, proposals: int = 4, prepared=None):
    """A start whose first ``proposals`` individuals are the regressor's proposals for ``views``
    (``ipm.learned.propose``: its most probable discrete joints), the rest :func:`preset_start`'s."""

    def start(problem: Problem, settings: MemeticSettings, rng: np.random.Generator,
              prepare=lambda z: z) -> list[Individual]:
        from ipm.learned.propose import propose

        zs = propose(problem, views, min(proposals, settings.population), prepared)
        return proposed_start(problem, settings, rng, prepare, zs, "learned")

    def elsewhere(problem: Problem, settings: MemeticSettings, rng: np.random.Generator, prepare, z: np.ndarray):
        """A start whose first individuals are the regressor's most probable joint for each plan
        (``Generator.plan_parameters``' values) other than ``z``'s, the rest :func:`preset_start`'s."""
        from ipm.learned.propose import propose

        spec, index = problem.spec, problem.spec.index
        x = spec.from_unit(z[: problem.n_shape])
        apart = {n: int(round(x[index[n]] - spec.lower[index[n]])) for n in problem.generator.plan_parameters}
        zs = propose(problem, views, prepared=prepared, apart=apart)
        return proposed_start(problem, settings, rng, prepare, zs, "other plan")

    start.learned = True  # the loop's memetic stage is shorter from it (LoopSettings.learned_generations)
    start.elsewhere = elsewhere  # the plan check's second stage (LoopSettings.plan_check)
    return start


def start_for(problem: Problem, views, start: str, proposals: int = 4, prepared=None):
    """The start of a fit of ``problem`` to ``views`` for the setting ``start``: ``learned`` is
    :func:`learned_start` where the regressor applies (a known camera, or an unknown one whose render
    camera it proposed; weights for the generator, ``prepared`` or shipped), else
    :func:`preset_start`, as ``presets`` is always."""
    from ipm.learned.propose import has_weights

    hidden = problem.camera is not None
    if start == "learned" and (not hidden or problem.camera.proposed) and \
            has_weights(problem.generator.name, prepared, camera_hidden=hidden):
        return learned_start(views, proposals, prepared)
    return preset_start
