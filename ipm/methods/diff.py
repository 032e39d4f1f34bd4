"""The differentiable path: memetic search at low resolution, then Adam at doubling resolutions.

Loss: mean over views of the pixel MSE between the rendered silhouette (``DiffProfile.renderer``)
and the reference mask, plus the generator's smoothness prior; for a generator with a ``mask_class`` (buildings:
windows) and views with semantic images, plus ``window_weight`` times the ``window_loss`` (MSE or Dice)
between the rendered and the reference masks of that class over a mean pyramid, and
``extra_class_weight`` times the same for each of its ``extra_mask_classes`` (buildings: roof;
without semantic images: the silhouette alone). Pose (yaw, tilts, translation, scale) is optimised with the shape
(``ipm.problem``); the tilts only where the profile allows them. Stages: memetic search, the
counts read off the class masks (:func:`read_counts_into`), discrete hill climb over the rest
(:func:`polish`), coarse-to-fine Adam with the counts read again before each stage and every
kind of a categorical part (a roof), as it stands and turned a quarter, tried before the last
(:func:`decide`; the default profile), for a camera of unknown field of view a sweep over its
focal length before the last (:func:`sweep_focal`), Occam step.
"""
from __future__ import annotations

import time
from dataclasses import asdict, replace
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pandas as pd
from tqdm import tqdm

from ipm.errors import UserError
from ipm.facades import marker_turn, read_counts
from ipm.generators import get_generator
from ipm.io import atomic_dir, load_views, save_glb, save_ply, write_json
from ipm.io.views import Views, resize_masks
from ipm.methods import check_generator
from ipm.optim.memetic import Batch, Individual, adam_steps, memetic
from ipm.photo import PITCH_PRIOR, fov_of
from ipm.problem import POSE_NAMES, Problem
from ipm.profiles import DiffProfile, get_profile
from ipm.render.edges import EdgeRenderer
from ipm.render.silhouette import SilhouetteRenderer


def class_masks(generator, views: Views, name: str | None = None) -> tuple[np.ndarray, int] | None:
    """The reference masks (n, H, W) of the semantic class ``name`` (default: the generator's
    ``mask_class``) and that class's label, or None when there is no such class or the views have
    no semantic images that name it."""
    name = generator.mask_class if name is None else name
    if name is None or views.semantics is None or name not in (views.semantic_labels or {}):
        return None
    value = int(views.semantic_labels[name])
    return (views.semantics == value).astype(np.float32), generator.semantic_labels[name]


def make_renderer(name: str, c2w: np.ndarray, fov_x: float, width: int, height: int, spp: int,
                  mitsuba_tuned: bool = False):
    """The silhouette renderer ``name`` (``DiffProfile.renderer``) for these cameras: ``auto`` is
    the JAX one (``ipm.render.edges``; with a class-mask term too: buildings' window masks agree
    with Mitsuba's on the dev split within the seeds' spread, docs/decisions.md, "Renderer auto")
    unless the path's settings were tuned with Mitsuba (``mitsuba_tuned``: a camera whose field of
    view is unknown too, ``ipm.photo``, whose focal sweep was; the JAX renderer is not validated
    there on the dev split. With the field of view given, the pitch starts were measured with JAX)."""
    if name == "jax" or (name == "auto" and not mitsuba_tuned):
        return EdgeRenderer(c2w, fov_x, width, height, spp)
    return SilhouetteRenderer(c2w, fov_x, width, height, spp)


class Objective:
    """Silhouette (and class mask) loss and gradient of ``z`` at one resolution and level of detail."""

    def __init__(self, problem: Problem, views: Views, width: int, lod: int, profile: DiffProfile):
        self.problem, self.lod, self.reg = problem, lod, profile.reg_weight
        self.targets = resize_masks(views.masks, width)
        h = self.targets.shape[1]
        self.renderer = make_renderer(profile.renderer, views.c2w, views.fov_x, width, h, profile.spp,
                                      mitsuba_tuned=problem.fov_estimated is True)
        gen, terms = problem.generator, []
        for name, weight in [(gen.mask_class, profile.window_weight)] + [(c, profile.extra_class_weight)
                                                                           for c in gen.extra_mask_classes]:
            masks = class_masks(gen, views, name) if weight > 0 else None
            if masks is not None and masks[1] in gen.part_semantic:
                terms.append((resize_masks(masks[0], width), masks[1], weight))
        self.class_targets = np.ascontiguousarray(np.stack([t[0] for t in terms], 1)) if terms else None
        self.class_labels = tuple(t[1] for t in terms)
        self.class_weight = tuple(t[2] for t in terms)
        self._part_class = np.zeros(len(gen.part_semantic), int)  # each part's face group (0: no class term)
        for k, label in enumerate(self.class_labels, start=1):
            self._part_class[np.asarray(gen.part_semantic) == label] = k
        self.class_levels, self.class_loss = profile.window_levels, profile.window_loss
        self.calls = 0
        self._shared = None  # the shared-positions rendering, built on first use

    def _groups(self, key) -> tuple:
        """(vertex_fn, face groups, V) to render ``key``'s topology: for a generator with shared
        positions the level's every face in each group and one vertex block per group (one scene,
        hence one set of compiled kernels, for all topologies: the same for every key); else the
        topology's faces, split by the mask classes when there are class terms (group k: the
        parts of the k-th class, group 0: the others)."""
        gen, part_class = self.problem.generator, self._part_class
        if gen.shared_positions:
            if self._shared is None:
                parts = np.arange(len(gen.part_names))
                groups = tuple(tuple(parts[part_class == k]) for k in range(len(self.class_labels) + 1))
                faces = gen.all_faces(self.lod)
                self._shared = (self.problem.group_vertex_fn(self.lod, groups), [faces] * len(groups),
                                int(faces.max()) + 1)
            return self._shared
        topo = gen.topology(key, self.lod)
        faces = [topo.faces] if not self.class_labels else [topo.faces[part_class[topo.labels] == k]
                                                              for k in range(len(self.class_labels) + 1)]
        return self.problem.vertex_fn(key, self.lod), faces, len(topo.uv)

    def __call__(self, z: np.ndarray, seed: int | None = None) -> tuple[float, np.ndarray]:
        """Loss and gradient at ``z``, rendered with ``seed`` (default: the count of calls so far)."""
        first = int(self.seeds(1)[0])
        fn, faces, n_vertices = self._groups(self.problem.key(z))
        loss, grad = self.renderer.loss_and_grad(fn, z, faces, n_vertices, self.targets,
                                                 seed=first if seed is None else seed,
                                                 highlight_targets=self.class_targets,
                                                 highlight_weight=self.class_weight,
                                                 highlight_levels=self.class_levels,
                                                 highlight_loss=self.class_loss)
        reg, reg_grad = self.problem.regulariser(z, self.reg)
        return loss + reg, grad + reg_grad

    def seeds(self, n: int) -> np.ndarray:
        """The render seeds of the next ``n`` evaluations, those calls one at a time would draw."""
        self.calls += n
        return np.arange(self.calls - n, self.calls)

    def batch(self, on: bool) -> Batch | None:
        """Batched evaluations for the memetic stage (``DiffProfile.memetic_batch``), or None: off,
        or a renderer other than JAX's silhouettes (class masks run one at a time)."""
        if not on or not isinstance(self.renderer, EdgeRenderer) or self.class_targets is not None:
            return None
        return Batch(self.seeds, self.many)

    def many(self, zs: list[np.ndarray], seeds) -> tuple[np.ndarray, np.ndarray]:
        """Losses (b,) and gradients (b, m) of the points ``zs`` rendered with ``seeds``: one JAX
        call per topology, padded to a power of 4 points (each size is a program to compile)."""
        losses, grads = np.empty(len(zs)), np.empty((len(zs), len(zs[0])))
        groups: dict = {}  # vertex function -> (faces, indices)
        for i, z in enumerate(zs):
            fn, faces, _ = self._groups(self.problem.key(z))
            groups.setdefault(fn, (faces, []))[1].append(i)
        for fn, (faces, idx) in groups.items():
            size = 4
            while size < len(idx):
                size *= 4
            pad = idx + idx[:1] * (size - len(idx))
            loss, grad = self.renderer.loss_and_grad_batch(fn, np.stack([zs[i] for i in pad]), faces, self.targets,
                                                           [int(seeds[i]) for i in pad])
            for k, i in enumerate(idx):
                reg, reg_grad = self.problem.regulariser(zs[i], self.reg)
                losses[i], grads[i] = loss[k] + reg, grad[k] + reg_grad
        return losses, grads

    def _render(self, z: np.ndarray) -> np.ndarray:
        fn, faces, n_vertices = self._groups(self.problem.key(z))
        out = self.renderer.render(np.asarray(fn(jnp.asarray(z, jnp.float32))).reshape(-1, n_vertices, 3), faces)
        return out if out.ndim == 3 else out[:, 0]  # the silhouette

    def match_area(self, z: np.ndarray, rounds: int = 2) -> np.ndarray:
        """Rescale ``z`` so its silhouettes cover as many pixels as the targets (a robust start:
        presets differ in proportions, so matching the anchor height alone can be far off)."""
        z = z.copy()
        i = self.problem.n_shape + POSE_NAMES.index("log_scale")
        for _ in range(rounds):
            area = self._render(z).sum()
            z[i] += 0.5 * np.log(self.targets.sum() / max(area, 1.0))
            z = self.problem.clip(z)
        return z


def initial_population(problem: Problem, profile: DiffProfile, rng: np.random.Generator,
                       prepare=lambda z: z) -> list[Individual]:
    """Presets and random samples, spread over yaw bins (the memetic algorithm's start) and, for an
    unknown camera, over its pitch (``UnknownCamera.spread``); ``prepare`` adjusts each start
    (e.g. its scale)."""
    presets = list(problem.generator.presets.items())
    n_random = int(round(profile.random_share * profile.population))
    bins = rng.permutation(np.resize(np.arange(profile.yaw_bins), max(profile.population, profile.yaw_bins)))
    cameras = [None] * profile.population
    if problem.camera is not None:
        cameras = problem.camera.spread(profile.population, rng)
    pop = []
    for i in range(profile.population):
        yaw = (bins[i] + rng.random()) / profile.yaw_bins * 2 * np.pi
        if i < profile.population - n_random:
            name, x = presets[i % len(presets)]
            u = problem.spec.to_unit(x)
        else:
            name, u = "random", rng.random(problem.n_shape)
        z = prepare(problem.initial_z(u, yaw, cameras[i]))
        pop.append(Individual(z, problem.key(z), name, lr=profile.lr))
    return pop


def _scorer(objective, seeds: tuple[int, ...]):
    """Loss of a point averaged over fixed render ``seeds`` (both sides of a comparison alike)."""
    return lambda x: float(np.mean([objective(x, seed=s)[0] for s in seeds]))


def simplify(problem: Problem, objective: Objective, z: np.ndarray, tolerance: float,
             record=lambda name, loss: None) -> np.ndarray:
    """Occam step: set each discrete parameter to its simplest value (``generator.simplest``)
    when that raises the loss by at most ``tolerance`` (relative): a part the views do not
    support (a handle hidden behind the body) is dropped. Both sides use the same render seeds."""
    spec, score = problem.spec, _scorer(objective, (10_001, 10_002))
    for name, value in getattr(problem.generator, "simplest", {}).items():
        i = spec.index[name]
        if spec.from_unit(z[: problem.n_shape])[i] == value:
            continue
        alt = z.copy()
        alt[i] = (value - spec.lower[i]) / (spec.upper[i] - spec.lower[i])
        loss, loss_alt = score(z), score(alt)
        record(f"{name}={value:g}", loss_alt)
        if loss_alt <= (1.0 + tolerance) * loss:
            z = alt
    return z


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
    alt = z.copy()
    alt[n] += np.pi
    out["yaw"] = [("yaw+180", problem.clip(alt))]
    return out


def _tried(problem: Problem, objective, alt: np.ndarray, name: str, steps: int, profile: DiffProfile, score,
           on_eval, record, clip=None) -> tuple[np.ndarray, float]:
    """The best point of ``steps`` Adam steps under ``objective`` from ``alt`` (``alt`` itself for
    none; projected by ``clip``, default ``problem.clip``) and its ``score``, recorded as
    ``name``: how polish, decide and the focal sweep try a candidate."""
    ind = Individual(alt, problem.key(alt), name, lr=profile.lr * 0.4)
    adam_steps(ind, steps, objective, clip or problem.clip, profile.reject_ratio, on_eval)
    cand = ind.z if ind.best_z is None else ind.best_z
    loss = score(cand)
    record(name, loss)
    return cand, loss


def polish(problem: Problem, objective, z: np.ndarray, profile: DiffProfile,
           on_eval=lambda ind: None, record=lambda name, loss: None, settled=frozenset()) -> np.ndarray:
    """Discrete hill climbing after the memetic stage: parameter by parameter (but those named in
    ``settled``), try the current point's :func:`neighbours` with a few Adam steps each
    (``polish_steps``) and move to the first that lowers the loss (same render seeds on both
    sides); up to ``polish_sweeps`` sweeps. The memetic stage moves one many-valued gene at a time
    by chance, so a window count one off on a facade would otherwise be left standing."""
    score = _scorer(objective, (10_003, 10_004))
    best = score(z)
    for _ in range(profile.polish_sweeps):
        improved = False
        for param in [p for p in neighbours(problem, z) if p not in settled]:
            for name, alt in neighbours(problem, z).get(param, []):
                cand, loss = _tried(problem, objective, alt, name, profile.polish_steps, profile, score, on_eval,
                                    record)
                if loss < best:
                    z, best, improved = cand, loss, True
                    break
        if not improved:
            break
    return z


def decide(problem: Problem, z: np.ndarray, profile: DiffProfile, steps_objective, score_objective,
           on_eval=lambda ind: None, record=lambda name, loss: None, recount=None) -> np.ndarray:
    """Every value of each categorical parameter (``Generator.categorical``: a roof's type) given
    ``decide_steps`` Adam steps under ``steps_objective`` from ``z``, the current value too (none
    is favoured by a longer refinement), and compared under ``score_objective`` (same render
    seeds): the lowest wins. Polish's few steps at the memetic resolution cannot carry a flat roof
    to a hip roof's basin (its walls and slope must move together). With ``recount`` (``z`` ->
    ``z`` with the counts the views show read in) each value is also tried turned a quarter
    (:func:`turned`): a near-square house fitted a quarter off with a pyramid-like hip roof
    matches a gable roof only turned, since a gable's ridge has a direction. With
    ``decide_rounds`` above 1 the candidates race: after each round the better half (at least
    two) get ``decide_steps`` more from where they stand, since the current value starts
    converged and a new roof is still descending when the first round ends. With
    ``decide_least`` the continuous parameters a value turns on start at their lower bounds; with
    ``decide_shares`` each value (and each turned) also starts with the height shared anew between
    roof and walls (``Generator.split_roof``)."""
    spec, n, gen = problem.spec, problem.n_shape, problem.generator
    score = _scorer(score_objective, (10_005, 10_006))
    for name in gen.categorical:
        i, on = spec.index[name], gen.active(spec.from_unit(z[:n]))
        if profile.decide_steps <= 0 or not on[i]:
            continue
        pool = []
        for k in range(int(spec.levels[i])):
            alt = z.copy()
            alt[i] = k / (spec.levels[i] - 1)
            if profile.decide_least:
                alt[:n][gen.active(spec.from_unit(alt[:n])) & ~on & ~spec.discrete] = 0.0
            value = f"{name}={spec.lower[i] + k:g}"
            splits = [(share, gen.split_roof(spec.from_unit(alt[:n]), share)) for share in profile.decide_shares]
            for tag, start in [(value, alt)] + [(f"{value} roof {share:g}", problem.with_shape(alt, x))
                                                for share, x in splits if x is not None]:
                pool += [(tag, start)] + ([(f"{tag} turned", recount(turned(problem, start, np.pi / 2)))]
                                          if recount is not None else [])
        for r in range(max(profile.decide_rounds, 1)):
            tried = [_tried(problem, steps_objective, start, tag if r == 0 else f"{tag} (round {r + 1})",
                            profile.decide_steps, profile, score, on_eval, record) for tag, start in pool]
            order = np.argsort([loss for _, loss in tried], kind="stable")
            pool = [(pool[j][0], tried[j][0]) for j in order[:race_survivors(len(pool))]]
        z = pool[0][1]
    return z


def race_survivors(candidates: int) -> int:
    """How many of ``candidates`` go on to :func:`decide`'s next round: the better half, at least two."""
    return min(candidates, max(2, (candidates + 1) // 2))


def decide_evaluations(candidates: int, profile: DiffProfile) -> int:
    """Adam steps :func:`decide` spends on ``candidates`` values of one parameter (progress bar)."""
    total = 0
    for _ in range(max(profile.decide_rounds, 1)):
        total += candidates * profile.decide_steps
        candidates = race_survivors(candidates)
    return total


def sight_axis(problem: Problem, views: Views, z: np.ndarray) -> tuple[int, np.ndarray] | None:
    """The :attr:`~ipm.generators.base.Generator.footprint` parameter (its index) whose side the
    first view looks along more nearly at ``z``'s pose, and the world step that moves the object
    by one unit of that parameter away from the camera; None without a footprint."""
    gen = problem.generator
    if gen.footprint is None:
        return None
    world = problem.to_world(z)
    origin, ends = world(np.zeros((1, 3)))[0], world(np.eye(3)[[0, 2]])
    axes = ends - origin  # the object's x and z axes in the world, times its scale
    along = axes @ (views.c2w[0, :3, 3] - origin)
    k = int(np.argmax(np.abs(along)))
    return problem.spec.index[gen.footprint[k]], -np.sign(along[k]) * axes[k]


def sweeps_sight(problem: Problem, profile: DiffProfile) -> bool:
    """Whether :func:`sweep_sight` runs: a generator with a footprint and a sweep in the profile."""
    return problem.generator.footprint is not None and profile.sight_steps > 0


def sight_evaluations(problem: Problem, profile: DiffProfile) -> int:
    """Adam steps :func:`sweep_sight` spends (progress bar)."""
    return sweeps_sight(problem, profile) * (len(profile.sight_factors) + 1) * profile.sight_steps


def _race(problem: Problem, steps_objective, z: np.ndarray, name: str, starts: list[tuple[str, np.ndarray]],
          steps: int, margin: float, profile: DiffProfile, score, on_eval, record) -> np.ndarray:
    """``z`` (recorded as ``name``) and each of ``starts`` (name, point) given ``steps`` Adam steps
    under ``steps_objective`` and compared by ``score``: the lowest start replaces ``z`` only if
    its loss is lower than ``z``'s by more than ``margin`` (a fraction). How the sweeps try starts
    the fit would not reach by itself."""
    kept = _tried(problem, steps_objective, z, name, steps, profile, score, on_eval, record)
    tried = [_tried(problem, steps_objective, alt, alt_name, steps, profile, score, on_eval, record)
             for alt_name, alt in starts]
    best = min(tried, key=lambda start: start[1], default=kept)
    return best[0] if best[1] < kept[1] * (1 - margin) else kept[0]


def sweep_sight(problem: Problem, views: Views, z: np.ndarray, profile: DiffProfile, steps_objective,
                score_objective, on_eval=lambda ind: None, record=lambda name, loss: None) -> np.ndarray:
    """The extent along the first view's line of sight tried at several values: ``z`` and ``z``
    with that :attr:`~ipm.generators.base.Generator.footprint` side times each of
    ``sight_factors`` (the face nearest the camera held in place, so the front stays where the
    image puts it), each given ``sight_steps`` Adam steps under ``steps_objective`` and compared
    under ``score_objective`` (same render seeds); the lowest loss wins if it is lower than the
    unstretched one's by more than ``sight_margin`` (a fraction). From one view that extent
    shows only in a sliver of side wall and in the roof's rise, which trade with the pose, so a fit
    keeps whatever extent it started from."""
    if not sweeps_sight(problem, profile):
        return z
    (i, away), spec, n = sight_axis(problem, views, z), problem.spec, problem.n_shape
    t = n + POSE_NAMES.index("dx")  # the translation genes dx, dy, dz
    x = spec.from_unit(z[:n])
    starts = []
    for factor in profile.sight_factors:
        alt_x = x.copy()
        alt_x[i] *= factor
        alt_x = spec.clip(alt_x)
        alt = problem.with_shape(z, alt_x)
        alt[t:t + 3] += away * (alt_x[i] - x[i]) / 2 / problem.anchor_s
        starts.append((f"sight x{factor:g}", problem.clip(alt)))
    return _race(problem, steps_objective, z, "sight x1", starts, profile.sight_steps, profile.sight_margin, profile,
                 _scorer(score_objective, (10_007, 10_008)), on_eval, record)


def sweeps_place(problem: Problem, profile: DiffProfile) -> bool:
    """Whether :func:`sweep_place` runs: a generator with ``placements`` and steps in the profile."""
    return bool(problem.generator.placements) and profile.place_steps > 0


def place_evaluations(problem: Problem, profile: DiffProfile) -> int:
    """Adam steps :func:`sweep_place` spends (progress bar)."""
    return sweeps_place(problem, profile) * (len(problem.generator.placements) + 1) * profile.place_steps


def sweep_place(problem: Problem, z: np.ndarray, profile: DiffProfile, steps_objective, score_objective,
                on_eval=lambda ind: None, record=lambda name, loss: None) -> np.ndarray:
    """A small part put in at each of the generator's :attr:`~ipm.generators.base.Generator.placements`
    (a building's chimney at nine places on the roof): ``z`` and ``z`` with each placement's
    values, each given ``place_steps`` Adam steps under ``steps_objective`` and compared under
    ``score_objective`` (same render seeds); the lowest loss wins if it is lower than ``z``'s by
    more than ``place_margin``. Such a part covers a few hundred pixels, and where it is not
    drawn its edges give no gradient, so a fit keeps it wherever the memetic stage left it (or
    leaves it out)."""
    if not sweeps_place(problem, profile):
        return z
    spec, n = problem.spec, problem.n_shape
    x = spec.from_unit(z[:n])
    starts = []
    for values in problem.generator.placements:
        alt_x = x.copy()
        alt_x[[spec.index[k] for k in values]] = list(values.values())
        starts.append(("place " + " ".join(f"{k}={v:g}" for k, v in values.items()), problem.with_shape(z, alt_x)))
    return _race(problem, steps_objective, z, "place kept", starts, profile.place_steps, profile.place_margin, profile,
                 _scorer(score_objective, (10_015, 10_016)), on_eval, record)


def sweeps_focal(problem: Problem, profile: DiffProfile) -> bool:
    """Whether :func:`sweep_focal` runs: a camera of unknown field of view and a sweep in the profile."""
    return problem.fov_estimated is True and profile.focal_sweep > 0 and profile.focal_steps > 0


def _walk(problem: Problem, z: np.ndarray, i: int, step: float, points: int, label, profile: DiffProfile,
          objective, score, on_eval, record) -> np.ndarray:
    """The gene ``i`` held at ``z``'s value and at ``points`` values on either side, ``step``
    apart, walking outwards with each point starting from its inner neighbour's result (a
    continuation: the rest follows the held gene a step at a time), everything else given
    ``focal_steps`` Adam steps under ``objective``; the point of lowest ``score`` (the same render
    seeds for all) wins. ``label(value)`` names a point in the trace."""
    def held(start: np.ndarray, value: float) -> tuple[np.ndarray, float]:
        alt = start.copy()
        alt[i] = value

        def clip(x):
            x = problem.clip(x)
            x[i] = value
            return x

        return _tried(problem, objective, alt, label(value), profile.focal_steps, profile, score, on_eval, record,
                      clip)

    centre = held(z, float(z[i]))
    tried = [centre]
    for direction in (-1, 1):
        point = centre
        for k in range(1, points + 1):
            value = float(z[i]) + direction * k * step
            if not problem.lower[i] <= value <= problem.upper[i]:
                break
            point = held(point[0], value)
            tried.append(point)
    return min(tried, key=lambda t: t[1])[0]


def sweep_focal(problem: Problem, z: np.ndarray, profile: DiffProfile, objective,
                on_eval=lambda ind: None, record=lambda name, loss: None) -> np.ndarray:
    """For an unknown camera whose field of view is not given: a profile of the loss over the
    focal length (:func:`_walk` over the focal gene, ``focal_sweep`` points either side,
    ``focal_step`` apart), then, with ``pitch_sweep``, over the pitch from the winner. The loss
    over the focal length is shallow (a few per cent between the truth's and a field of view 40 %
    too wide, cup_1), too shallow for Adam to cross with everything else moving; and a far focal
    length started from a point fitted to another scores worse than its own basin would, hence
    the walk. The pitch trades with the shape along a valley Adam crawls (dev building_d3 and d4
    stopped 0.25-0.35 degrees off with the true camera's basin 3-6 % lower in loss)."""
    if not sweeps_focal(problem, profile):
        return z
    camera = problem.camera
    score = _scorer(objective, (10_009, 10_010, 10_011, 10_012))
    z = _walk(problem, z, problem.camera_gene("log_focal"), profile.focal_step, profile.focal_sweep,
              lambda v: f"fov={np.degrees(fov_of(v, camera.fov0)):.1f}", profile, objective, score, on_eval, record)
    if profile.pitch_sweep > 0:
        z = _walk(problem, z, problem.camera_gene("pitch"), np.radians(profile.pitch_step), profile.pitch_sweep,
                  lambda v: f"pitch={np.degrees(v):.2f}", profile, objective, score, on_eval, record)
    return z


def pitch_niche(problem: Problem, bins: int):
    """``z`` -> its bin of an unknown camera's pitch, ``bins`` equal bins over ``PITCH_PRIOR``
    (the ends open): the memetic stage's niches (``DiffProfile.pitch_bins``). Always 0 for a known
    camera or one bin."""
    if problem.camera is None or bins <= 1:
        return lambda z: 0
    i, (lo, hi) = problem.camera_gene("pitch"), PITCH_PRIOR
    return lambda z: int(np.clip((z[i] - lo) / (hi - lo) * bins, 0, bins - 1))


def pitch_starts(problem: Problem, profile: DiffProfile) -> list[dict[int, float]]:
    """The genes each memetic run holds (``DiffProfile.pitch_starts``): a run holding nothing, and
    for an unknown camera whose field of view is given one more per pitch start."""
    if problem.fov_estimated in (None, True) or not profile.pitch_starts:  # known camera, or FOV estimated
        return [{}]
    i = problem.camera_gene("pitch")
    return [{}] + [{i: float(np.radians(p))} for p in profile.pitch_starts]


def finalists(problem: Problem, final: list[Individual], k: int) -> list[Individual]:
    """Up to ``k`` of the memetic stage's last generation (best first) that differ from every one
    taken before in their topology or by more than a quarter turn in yaw: the basins worth a
    refinement of their own (the memetic resolution cannot tell a low gable roof from a hip)."""
    out = []
    for ind in final:
        yaw = ind.best_z[problem.n_shape]
        if all(problem.key(ind.best_z) != problem.key(o.best_z)
               or abs(np.angle(np.exp(1j * (yaw - o.best_z[problem.n_shape])))) > np.pi / 4 for o in out):
            out.append(ind)
        if len(out) == k:
            break
    return out


def _choose(zs: list[np.ndarray], objective, record) -> np.ndarray:
    """The point of ``zs`` with the lowest loss under ``objective`` (same render seeds for all)."""
    score = _scorer(objective, (10_007, 10_008))
    losses = [score(z) for z in zs]
    for i, loss in enumerate(losses):
        record(f"finalist {i}", loss)
    return zs[int(np.argmin(losses))]


def turned(problem: Problem, z: np.ndarray, angle: float) -> np.ndarray:
    """``z`` turned by ``angle`` about +y; a quarter turn also trades the footprint's sides
    (``Generator.quarter_turned``), so that the turned object covers the same ground."""
    n = problem.n_shape
    if abs(np.cos(angle)) < 0.5:
        z = problem.with_shape(z, problem.generator.quarter_turned(problem.spec.from_unit(z[:n])))
    z = np.array(z, np.float64)
    z[n] += angle
    return problem.clip(z)


def read_counts_into(problem: Problem, views: Views,
                     z: np.ndarray) -> tuple[np.ndarray, list[str], frozenset[str]]:
    """``z`` turned when the views' marker class says it faces the wrong way
    (:func:`ipm.facades.marker_turn`: a door on the back or a side), then with the counts the input views'
    class masks show set to what they show (:func:`ipm.facades.read_counts` on the facades the
    views face; a storey more or less keeps the walls' height: ``Generator.change_count``); the
    changes made; and the counts the views settle, for :func:`polish` to leave: those read (the
    next reading would set them again) and those of sides no view faces (no loss tells their
    values apart). ``z`` itself, no change and
    nothing settled when the views have no class masks or the generator no facades."""
    gen, spec, n = problem.generator, problem.spec, problem.n_shape
    masks = class_masks(gen, views)
    if masks is None or not gen.counts:
        return z, [], frozenset()
    changes = []
    marker = class_masks(gen, views, gen.marker[0]) if gen.marker else None
    turn = 0.0 if marker is None else marker_turn(gen, spec.from_unit(z[:n]), problem.to_world(z), views, marker[0])
    if turn:
        z = turned(problem, z, turn)
        changes.append(f"yaw{np.degrees(turn):+.0f}")
    x = spec.from_unit(z[:n])
    pose = problem.decode(z)["pose"]
    seen = gen.seen_counts(pose["yaw"], views.c2w[:, :3, 3] - np.asarray(pose["translation"]))
    found = read_counts(gen, x, problem.to_world(z), seen, views, masks[0], views.masks)
    for name, value in found.items():
        if value != round(x[spec.index[name]]):
            x = gen.change_count(x, name, value)
            changes.append(f"{name}={value}")
    return problem.with_shape(z, x), changes, frozenset(found) | (frozenset(gen.counts) - frozenset(seen))


def input_iou(problem: Problem, views: Views, z: np.ndarray, lod: int, res: int = 128) -> float:
    """Mean IoU of the input masks and the silhouettes of ``z``'s mesh from the input cameras (open3d
    ray casting at ``res`` px): the trace's progress in the metric's own terms. NaN where the
    cameras are not known (a photo), the images are not square or open3d is not installed (the GPU
    machine: the value only annotates the trace, so the fit itself runs without it)."""
    import importlib.util

    import trimesh

    from ipm.metrics.silhouette import raycast_masks, view_ious

    if (views.camera is not None or views.width != views.height or views.masks is None
            or importlib.util.find_spec("open3d") is None):
        return float("nan")
    mesh, res = problem.world_mesh(z, lod), min(res, views.width)
    rec = raycast_masks(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), list(views.c2w), res,
                        float(np.degrees(views.fov_x)))
    return float(view_ious(resize_masks(views.masks, res) > 0.5, rec).mean())


def reconstruct(problem: Problem, views: Views, profile: DiffProfile, seed: int = 0,
                progress: bool = True) -> tuple[np.ndarray, pd.DataFrame]:
    """Best ``z`` for ``views`` and the trace (one row per evaluation; at the end of each stage its
    ``iou`` column holds the input-view IoU of the stage's best, :func:`input_iou`)."""
    rng = np.random.default_rng(seed)
    reads = profile.read_counts and profile.window_weight > 0  # counts read off the class masks
    turns = profile.decide_turns and bool(problem.generator.marker)  # decide tries quarter turns too
    starts, niche = pitch_starts(problem, profile), pitch_niche(problem, profile.pitch_bins)
    memetic_evals = profile.ga_iterations * (profile.adam_per_iteration + profile.population)
    total = (len(starts) * memetic_evals + sum(profile.refine_iterations)
             + len(profile.refine_res)
             + sum(decide_evaluations(int(problem.spec.levels[problem.spec.index[c]]) * (1 + turns)
                                      * (1 + len(profile.decide_shares)), profile)
                   for c in problem.generator.categorical)
             + sight_evaluations(problem, profile)
             + place_evaluations(problem, profile)
             + (profile.refine_candidates - 1) * (profile.refine_iterations[0] + 1)
             + sweeps_focal(problem, profile) * (2 * profile.focal_sweep + 1 + 2 * profile.pitch_sweep
                  + (profile.pitch_sweep > 0)) * profile.focal_steps)
    bar = tqdm(total=total, desc="reconstruct", unit="eval", disable=not progress, leave=False)
    rows, t0 = [], time.perf_counter()
    state = {"stage": "memetic", "res": profile.memetic_res, "best": np.inf}

    def on_eval(ind: Individual) -> None:
        state["best"] = min(state["best"], ind.best_loss)
        rows.append((state["stage"], state["res"], len(rows), ind.origin, ind.loss, state["best"],
                     time.perf_counter() - t0))
        bar.update(1)
        bar.set_postfix(stage=state["stage"], res=state["res"], best=f"{state['best']:.5f}")

    def recorder(stage: str, res: int):
        """A trace row per candidate a stage scores by name (polish, decide, simplify)."""
        return lambda name, loss: rows.append((stage, res, len(rows), name, loss, min(state["best"], loss),
                                               time.perf_counter() - t0))

    levels, least = problem.spec.levels, problem.generator.min_fit_lod
    ious = {}

    def checkpoint(z: np.ndarray) -> None:
        """The input-view IoU of the current stage's best, on the stage's last trace row."""
        ious[len(rows) - 1] = input_iou(problem, views, z, max(profile.refine_lod, least))

    def read(z: np.ndarray, res: int) -> tuple[np.ndarray, frozenset[str]]:
        """``z`` with the counts the views show read in (trace rows for the changes), and the
        counts they settle; ``z`` and none without reading."""
        if not reads:
            return z, frozenset()
        z, changes, settled = read_counts_into(problem, views, z)
        rows.extend(("read", res, len(rows), c, np.nan, state["best"], time.perf_counter() - t0) for c in changes)
        return z, settled

    objective = Objective(problem, views, state["res"], max(profile.memetic_lod, least), profile)
    final = []
    for held in starts:
        with problem.holding(held):
            start = initial_population(problem, profile, rng, objective.match_area)
            final += memetic(start, objective, problem.clip, problem.key, problem.n_shape, levels, profile, rng,
                             on_eval, prepare=objective.match_area, yaw_free=problem.yaw_free, niche=niche,
                             batch=objective.batch(profile.memetic_batch))
    final.sort(key=lambda ind: ind.best_loss)
    checkpoint(final[0].best_z)
    state["stage"] = "polish"
    zs = []
    for ind in finalists(problem, final, profile.refine_candidates):
        z, settled = read(ind.best_z, state["res"])
        zs.append(polish(problem, objective, z, profile, on_eval, recorder("polish", state["res"]), settled))
    checkpoint(zs[0])
    for stage, (res, iters) in enumerate(zip(profile.refine_res, profile.refine_iterations)):
        previous, objective = objective, Objective(problem, views, res, max(profile.refine_lod, least), profile)
        if profile.recentre:
            zs = [problem.recentred(z) for z in zs]
        if stage == len(profile.refine_res) - 1 and profile.decide_steps > 0 and problem.generator.categorical:
            state["stage"] = "decide"
            recount = (lambda z: read_counts_into(problem, views, z)[0] if reads else z) if turns else None
            zs = [decide(problem, z, profile, previous, objective, on_eval, recorder("decide", res), recount)
                  for z in zs]
        if stage == len(profile.refine_res) - 1 and sweeps_sight(problem, profile):
            state["stage"] = "sight"
            zs = [sweep_sight(problem, views, z, profile, previous, objective, on_eval, recorder("sight", res))
                  for z in zs]
        if stage == len(profile.refine_res) - 1 and sweeps_place(problem, profile):
            state["stage"] = "place"
            zs = [sweep_place(problem, z, profile, previous, objective, on_eval, recorder("place", res)) for z in zs]
        if stage == len(profile.refine_res) - 1 and sweeps_focal(problem, profile):
            state.update(stage="focal", res=res)  # its steps run at this stage's size (decide's, sight's and
            # place's at the one before)
            zs = [sweep_focal(problem, z, profile, objective, on_eval, recorder("focal", res)) for z in zs]
        refined = []
        for z in zs:
            z = read(z, res)[0]
            state.update(stage="refine", res=res, best=np.inf)
            ind = Individual(z, problem.key(z), "refine", lr=profile.lr * 0.4)
            adam_steps(ind, iters + 1, objective, problem.clip, profile.reject_ratio, on_eval)
            refined.append(ind.best_z)
        zs = [_choose(refined, objective, recorder("choose", res))] if len(refined) > 1 else refined
        checkpoint(zs[0])
    z = zs[0]
    state["stage"] = "simplify"
    z = simplify(problem, objective, z, profile.occam_tolerance, recorder("simplify", state["res"]))
    checkpoint(z)
    bar.close()
    trace = pd.DataFrame(rows, columns=["stage", "res", "eval", "origin", "loss", "best", "seconds"])
    trace["iou"] = pd.Series(ious, dtype=float)
    return z, trace


def fit(views: Views, generator: str, profile: str, seed: int, progress: bool, **overrides):
    """The diff path on ``views``: the problem, its best ``z``, the trace and the profile (for a
    camera of unknown field of view and a ``fov_grid``, :func:`fit_fov_grid`)."""
    check_generator("diff", generator)
    prof = get_profile(profile, **overrides)
    if prof.fov_grid and views.camera is not None and not views.camera.fov_known:
        return (*fit_fov_grid(views, generator, prof, seed, progress), prof)
    problem = Problem.for_views(get_generator(generator), views, max_tilt=prof.max_tilt)
    z, trace = reconstruct(problem, views, prof, seed=seed, progress=progress)
    return problem, z, trace, prof


def final_score(problem: Problem, views: Views, z: np.ndarray, prof: DiffProfile) -> float:
    """Loss of ``z`` at the last refinement resolution over fixed render seeds: fits of the same
    mask under different held cameras compared alike (:func:`fit_fov_grid`)."""
    lod = max(prof.refine_lod, problem.generator.min_fit_lod)
    return _scorer(Objective(problem, views, prof.refine_res[-1], lod, prof), (10_007, 10_008))(z)


def fit_at_fov(views: Views, generator: str, prof: DiffProfile, seed: int, progress: bool,
               fov_deg: float) -> tuple[Problem, np.ndarray, pd.DataFrame, float]:
    """One point of :func:`fit_fov_grid`: the fit of ``views`` (an unknown camera) with its field
    of view held at ``fov_deg``, and its :func:`final_score`."""
    camera = replace(views.camera, fov0=float(np.radians(fov_deg)), fov_known=True, fov_chosen=True)
    held = replace(views, fov_x=camera.fov0, camera=camera)
    problem = Problem.for_views(get_generator(generator), held, max_tilt=prof.max_tilt)
    z, trace = reconstruct(problem, held, prof, seed=seed, progress=progress)
    return problem, z, trace, final_score(problem, held, z, prof)


def fit_fov_grid(views: Views, generator: str, prof: DiffProfile, seed: int,
                 progress: bool) -> tuple[Problem, np.ndarray, pd.DataFrame]:
    """An unknown field of view chosen from ``prof.fov_grid``: a fit per value with it held
    (:func:`fit_at_fov`, the same seed each), the one of lowest score kept; its trace gets a
    ``fov grid`` row per value (the score as its loss, the fits' seconds summed)."""
    fits = []
    for k, f in enumerate(prof.fov_grid):
        if progress:
            tqdm.write(f"field of view {f:g} degrees ({k + 1} of {len(prof.fov_grid)})")
        fits.append(fit_at_fov(views, generator, prof, seed, progress, f))
    problem, z, trace, _ = min(fits, key=lambda fit: fit[3])
    seconds = np.cumsum([float(fit[2]["seconds"].iloc[-1]) for fit in fits])
    rows = pd.DataFrame({"stage": "fov grid", "res": prof.refine_res[-1], "eval": len(trace) + np.arange(len(fits)),
                         "origin": [f"fov={f:g}" for f in prof.fov_grid], "loss": [fit[3] for fit in fits],
                         "best": float(trace["best"].iloc[-1]), "seconds": seconds})
    return problem, z, pd.concat([trace, rows], ignore_index=True)


def write_result(out: str | Path, problem: Problem, z: np.ndarray, trace: pd.DataFrame, prof: DiffProfile,
                 info: dict, seconds: float, place: np.ndarray | None = None) -> dict:
    """mesh.ply, mesh.glb, params.json (``info`` with the decoded ``z``), trace.csv and
    timing.json in ``out``, atomically; ``place`` (4 x 4, a similarity) moves the mesh first."""
    mesh = problem.world_mesh(z, max(prof.output_lod, problem.generator.min_fit_lod))
    if place is not None:
        mesh = replace(mesh, vertices=mesh.vertices @ place[:3, :3].T + place[:3, 3],
                       normals=mesh.normals @ (place[:3, :3] / np.cbrt(np.linalg.det(place[:3, :3]))).T)
    if not np.all(np.isfinite(mesh.vertices)):
        raise FloatingPointError("the reconstruction diverged (non-finite vertices)")
    info = {**problem.decode(z), "final_loss": float(trace["best"].iloc[-1]), "evaluations": len(trace),
            "settings": asdict(prof), **info}
    with atomic_dir(out) as tmp:
        save_ply(tmp / "mesh.ply", mesh.vertices, mesh.faces, mesh.labels)
        save_glb(tmp / "mesh.glb", mesh.vertices, mesh.faces, mesh.labels, mesh.part_names, mesh.uv,
                 normals=mesh.normals, extras={k: info[k] for k in ("generator", "params", "pose")})
        write_json(tmp / "params.json", info)
        trace.to_csv(tmp / "trace.csv", index=False)
        write_json(tmp / "timing.json", {"seconds": seconds, "evaluations": len(trace)})
    return info


def run_diff(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
             seed: int = 0, progress: bool = True, n_input_views: int | None = None, **overrides) -> dict:
    """``ipm reconstruct --method diff``: write mesh.ply, mesh.glb, params.json, trace.csv, timing.json."""
    t0 = time.perf_counter()
    views = load_views(views_path).first(n_input_views)
    problem, z, trace, prof = fit(views, generator, profile, seed, progress, **overrides)
    info = {"method": "diff", "profile": profile, "seed": seed, **views.input_frame()}
    return write_result(out, problem, z, trace, prof, info, time.perf_counter() - t0)


def run_photo(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
              seed: int = 0, progress: bool = True, n_input_views: int | None = 1, fov_given: bool = False,
              **overrides) -> dict:
    """The benchmark's camera-withheld row: the first view's mask alone, without its camera or field
    of view (with ``fov_given``, with its field of view), goes to the diff path (``ipm.photo``);
    only afterwards, to score it, the result is placed in the views' world by taking the estimated
    camera to the given one's position and heading, keeping the ground and the vertical
    (:func:`ipm.photo.registration`), and the camera's errors are recorded in params.json."""
    from ipm.photo import DEFAULT_FOV, camera_errors, placed_pose, registration, unknown_camera_views

    t0 = time.perf_counter()
    given = load_views(views_path).first(1)
    photo = unknown_camera_views(given if fov_given else replace(given, fov_x=DEFAULT_FOV), fov_known=fov_given)
    problem, z, trace, prof = fit(photo, generator, profile, seed, progress, **overrides)
    estimate = problem.decode(z)
    place = registration(estimate["camera"], given.c2w[0])
    info = {"method": "photo_fov" if fov_given else "photo", "profile": profile, "seed": seed,
            "pose": placed_pose(estimate["pose"], place),
            "photo_pose": estimate["pose"], "camera_error": camera_errors(estimate["camera"], given.c2w[0],
                                                                           given.fov_x)}
    return write_result(out, problem, z, trace, prof, info, time.perf_counter() - t0, place=place)


def run_photo_fov(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
                  seed: int = 0, progress: bool = True, n_input_views: int | None = 1, **overrides) -> dict:
    """The camera-withheld row with the field of view given, as a photo's Exif gives it: pitch,
    roll, pose and shape estimated (:func:`run_photo`)."""
    return run_photo(views_path, out, generator, profile, seed, progress, n_input_views, fov_given=True, **overrides)
