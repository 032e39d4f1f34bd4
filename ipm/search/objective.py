"""The differentiable path's loss: silhouettes (and a generator's class masks) of ``z`` against the input views.

Loss: mean over views of the pixel MSE between the rendered silhouette (``ObjectiveSettings.renderer``)
and the reference mask, plus the generator's smoothness prior; for a generator with a ``mask_class``
(buildings: windows) and views with semantic images, plus ``window_weight`` times the
``window_loss`` (MSE or Dice) between the rendered and the reference masks of that class over a
mean pyramid.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import jax.numpy as jnp
import numpy as np

from ipm import lanes
from ipm.io.views import Views, resize_masks
from ipm.problem import POSE_NAMES, Problem
from ipm.render.edges import EdgeRenderer
from ipm.render.silhouette import SilhouetteRenderer
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class ObjectiveSettings(Settings):
    """What the differentiable path's loss renders and weighs."""

    KIND = "diff setting"
    reg_weight: Annotated[float, at_least(0.0)] = 0.33
    """Weight of the parameter regulariser (smoothness of the handle's control sequences)."""
    spp: Annotated[int, at_least(1)] = 4
    """Samples per pixel of the silhouette renders."""
    renderer: Literal["auto", "jax", "mitsuba"] = "auto"
    """Silhouette renderer: ``jax`` (``ipm.render.edges``), ``mitsuba`` (``ipm.render.silhouette``) or ``auto``:
    jax, but Mitsuba for an unknown camera whose field of view is estimated (docs/decisions.md, 'Renderer auto')."""
    window_weight: Annotated[float, Range(0.0, 100.0)] = 1.0
    """Weight of the class-mask term beside the silhouette (the generator's ``mask_class``:
    buildings' windows; used when the views have semantic images); 0 = the silhouette alone
    (docs/decisions.md, 'Window term')."""
    window_levels: Annotated[int, at_least(1)] = 4
    """Levels of the 2 x 2 mean pyramid over which the class-mask term is averaged (1: the
    full-resolution MSE alone)."""
    window_loss: Literal["mse", "dice"] = "mse"
    """Loss of the class-mask term on each pyramid level: ``mse`` or ``dice``
    (``ipm.render.silhouette._pyramid_loss``; ``dice`` wants a weight of about 0.01;
    docs/decisions.md, 'Window term')."""


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
                  mitsuba_tuned: bool = False, closed: bool = False):
    """The silhouette renderer ``name`` (``ObjectiveSettings.renderer``) for these cameras: ``auto`` is
    the JAX one (``ipm.render.edges``; with a class-mask term too: buildings' window masks agree
    with Mitsuba's on the dev split within the seeds' spread, docs/decisions.md, "Renderer auto")
    unless the path's settings were tuned with Mitsuba (``mitsuba_tuned``: a camera whose field of
    view is unknown too, ``ipm.photo``, whose focal sweep was; the JAX renderer is not validated
    there on the dev split. With the field of view given, the pitch starts were measured with JAX).
    ``closed``: every mesh is closed, outward-facing solids (the JAX renderer draws front faces only)."""
    if renderer_kind(name, mitsuba_tuned) == "jax":
        return EdgeRenderer(c2w, fov_x, width, height, spp, cull_back=closed)
    return SilhouetteRenderer(c2w, fov_x, width, height, spp)


def renderer_kind(name: str, mitsuba_tuned: bool = False) -> str:
    """``jax`` or ``mitsuba``: the renderer :func:`make_renderer` makes for ``name``."""
    return "jax" if name == "jax" or (name == "auto" and not mitsuba_tuned) else "mitsuba"


class Objective:
    """Silhouette (and class mask) loss and gradient of ``z`` at one resolution and level of detail."""

    def __init__(self, problem: Problem, views: Views, width: int, lod: int, profile: ObjectiveSettings):
        self.problem, self.lod, self.reg, self.width = problem, lod, profile.reg_weight, width
        self.targets = resize_masks(views.masks, width)
        self.object_share = float(np.mean(self.targets))
        """The object's share of the pixels the silhouette loss averages: a rise of the loss by
        ``a * object_share`` is a share ``a`` of the object's pixels (the Occam margins)."""
        h = self.targets.shape[1]
        gen, terms = problem.generator, []
        self.renderer = make_renderer(profile.renderer, views.c2w, views.fov_x, width, h, profile.spp,
                                      mitsuba_tuned=problem.fov_estimated is True, closed=gen.closed_solids)
        masks = class_masks(gen, views) if profile.window_weight > 0 else None
        if masks is not None and masks[1] in gen.part_semantic:
            terms.append((resize_masks(masks[0], width), masks[1], profile.window_weight))
        self.class_targets = np.ascontiguousarray(np.stack([t[0] for t in terms], 1)) if terms else None
        self.class_labels = tuple(t[1] for t in terms)
        self.class_weight = tuple(t[2] for t in terms)
        self._part_class = np.zeros(len(gen.part_semantic), int)  # each part's face group (0: no class term)
        for k, label in enumerate(self.class_labels, start=1):
            self._part_class[np.asarray(gen.part_semantic) == label] = k
        self.class_levels, self.class_loss = profile.window_levels, profile.window_loss
        self.calls = 0
        self._shared = None  # the shared-positions rendering, built on first use
        self._split: dict = {}  # topology key -> its faces per group, split once

    def _groups(self, key) -> tuple:
        """(vertex_fn, face groups, V) to render ``key``'s topology: the topology's faces, split by
        the mask classes when there are class terms (group k: the parts of the k-th class, group 0:
        the others). For a generator with shared positions, one vertex block per group from one
        program for all topologies; there a renderer other than the JAX one with class terms (whose
        programs take any faces of a padded size) draws the level's every face in each group, so
        that one scene (a Mitsuba scene costs seconds of kernel compilation) serves every key."""
        gen, part_class = self.problem.generator, self._part_class
        topo = gen.topology(key, self.lod)
        if key not in self._split:
            self._split[key] = [topo.faces] if not self.class_labels else [
                topo.faces[part_class[topo.labels] == k] for k in range(len(self.class_labels) + 1)]
        faces = self._split[key]
        if not gen.shared_positions:
            return self.problem.vertex_fn(key, self.lod), faces, topo.n_vertices
        if self._shared is None:
            parts = np.arange(len(gen.part_names))
            groups = tuple(tuple(parts[part_class == k]) for k in range(len(self.class_labels) + 1))
            every = gen.all_faces(self.lod)
            self._shared = (self.problem.group_vertex_fn(self.lod, groups), [every] * len(groups),
                            int(every.max()) + 1)
        if self.class_labels and isinstance(self.renderer, EdgeRenderer):
            return self._shared[0], faces, self._shared[2]
        return self._shared

    def __call__(self, z: np.ndarray, seed: int | None = None) -> tuple[float, np.ndarray]:
        """Loss and gradient at ``z``, rendered with ``seed`` (default: the count of the calls so far
        that drew theirs: a score at fixed seeds leaves the later draws as they were, so a move
        that scores more or fewer points does not change the Adam runs after it)."""
        seed = int(self.seeds(1)[0]) if seed is None else seed
        fn, faces, n_vertices = self._groups(self.problem.key(z))
        loss, grad = self.renderer.loss_and_grad(fn, z, faces, n_vertices, self.targets, seed=seed,
                                                 highlight_targets=self.class_targets,
                                                 highlight_weight=self.class_weight,
                                                 highlight_levels=self.class_levels,
                                                 highlight_loss=self.class_loss)
        reg, reg_grad = self.problem.regulariser(z, self.reg)
        return loss + reg, grad + reg_grad

    def seeds(self, n: int) -> np.ndarray:
        """The render seeds of the next ``n`` evaluations, those calls one at a time would draw (a
        try run beside others draws those it would draw after the tries before it: ``ipm.lanes``)."""
        drawn = lanes.draw(self, n)
        if drawn is not None:
            return drawn
        self.calls += n
        return np.arange(self.calls - n, self.calls)

    def rewind(self) -> None:
        """The next evaluation draws the first render seed again: a move's or a stage's draws do not
        depend on how many evaluations the moves before it made (within a try run beside others,
        the try's own seeds: ``ipm.lanes``)."""
        if not lanes.rewind(self):
            self.calls = 0

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
