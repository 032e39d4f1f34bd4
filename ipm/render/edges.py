"""Silhouettes (and class masks) in JAX: scanline coverage and edge-sampling gradients (the paper's own renderer).

The paper's last section replaces Mitsuba by "our own simple implementation of differentiable
renderer that uses edge sampling" for silhouettes. This is one, in pure JAX, so that the generator,
the camera, the coverage and the gradient are one ``jax.jit`` function of the parameters.

The kernels: coverage and its gradient in ``ipm.render.edge_scan``, class masks in
``ipm.render.edge_classes``; their compiled programs and budgets in ``ipm.render.edge_programs``.
"""
from __future__ import annotations

import threading
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ipm import lanes
from ipm.render.edge_classes import front_facing, pyramid_loss  # noqa: F401  (pyramid_loss re-exported)
from ipm.render.edge_programs import (  # noqa: F401  (_silhouette_loss re-exported)
    _class_loss_fn, _class_render_fn, _class_sizes, _face_classes, _faces_key, _loss_fn, _pullback, _render_fn,
    SMALL_IMAGE, _round_up, _silhouette_loss, padded, split, with_headroom,
)
from ipm.render.edge_scan import camera_arrays, project, row_ranges, supersampling
from ipm.render.silhouette import group_count as _group_count, highlight_arrays


class EdgeRenderer:
    """Silhouettes of one triangle mesh seen by a fixed set of cameras, in JAX, with edge-sampling
    gradients: the same interface as ``ipm.render.silhouette.SilhouetteRenderer``, further face
    groups (a building's windows, its roof) included: each one's mask where visible (a z-buffer per
    sample) and each class term's gradient by edge sampling at the class's visible boundary.

    Parameters
    ----------
    c2w : (n, 4, 4) OpenGL camera-to-world matrices.
    fov_x : horizontal field of view in radians.
    width, height : image size in pixels.
    spp : samples per pixel and scan direction (rounded to a square: 4 -> 2 x 2; rows and
        columns each take that many, so a pixel's value averages twice ``spp`` samples).
    spans : the first span budget of :func:`~ipm.render.edge_scan.spans` (default: from the first
        mesh drawn); it grows when a mesh needs more (each size is compiled once). With further face
        groups it is also the first fragment budget of :func:`~ipm.render.edge_classes.visible_faces`.
    cull_back : with further face groups, draw only the triangles facing the camera: the same
        images for meshes of closed, outward-facing solids (a building's), from half the work.
    """

    def __init__(self, c2w: np.ndarray, fov_x: float, width: int, height: int, spp: int = 4,
                 spans: int | None = None, cull_back: bool = False):
        self.c2w, self.fov_x, self.width, self.height = np.asarray(c2w), fov_x, int(width), int(height)
        self.spp, self.ss = spp, supersampling(spp)
        self.w2c, self.focal = camera_arrays(self.c2w, fov_x, self.width)
        self._w2c = jnp.asarray(self.w2c)
        self.spans, self.cull = spans, bool(cull_back)
        self._small = max(self.width, self.height) <= SMALL_IMAGE  # budgets in powers of two (_round_up)
        self._budgets: dict = {}
        self._faces: dict = {}
        self._blocks: dict = {}
        self._classes: dict = {}  # class key -> each face's class on the device
        self._device: dict = {}  # id -> (a caller's array, its device copy): :meth:`_on_device`
        self._lock = threading.Lock()

    def needed(self, vertices: np.ndarray, faces: np.ndarray, classes: np.ndarray | None = None) -> tuple[int, int]:
        """The spans and (with ``classes``) fragments the mesh (``vertices`` (V, 3), ``faces``
        (F, 3)) needs in its costliest view and scan direction: the work its image takes."""
        v = np.asarray(vertices, np.float32).reshape(-1, 3)
        need, frags = 0, 0
        for m in self.w2c:
            xy, front = project(v, m, self.focal, self.width, self.height, np)
            tri = (xy * self.ss)[faces]
            e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
            area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
            drawn = (front_facing(e1, e2) if self.cull else area > 0) if classes is not None else True
            ok = front[faces].all(1) & drawn  # view_class_area's
            for axis, size in ((1, self.height), (0, self.width)):
                rows = row_ranges(tri[..., axis], ok, size * self.ss, np)[1]
                need = max(need, int(rows.sum()))
                frags = max(frags, int(area[ok].sum() + rows.sum()))
        return need, frags

    def _budget(self, key, vertices, faces: np.ndarray, classes: np.ndarray | None = None) -> int | tuple[int, int]:
        """The span budget for meshes of ``key`` (with ``classes``, the span and fragment budgets):
        on first sight ``spans``, or what ``vertices`` (a callable giving them) need (:meth:`needed`)
        with :func:`with_headroom`, so that the search rarely outgrows it."""
        budgets = lanes.table(self._budgets)  # a try's own copy where tries run side by side
        if key not in budgets:
            if self.spans:
                budgets[key] = int(self.spans) if classes is None else (int(self.spans), int(self.spans))
                return budgets[key]
            need, frags = self.needed(vertices(), faces, classes)
            spans = _round_up(with_headroom(need, grown=False) + 256, self._small)
            budgets[key] = spans if classes is None else (
                spans, _round_up(with_headroom(frags, grown=False) + 256, self._small))
        return budgets[key]

    def _run(self, key, groups: np.ndarray, vertices, run, classes: np.ndarray | None = None, budget_key=None):
        """``run(faces, budget)`` -> (results..., budgets needed per view) with the budget of
        ``budget_key`` (default ``key``; :meth:`_budget`), each grown and run again while the mesh
        needs more than it has; the faces are put on the device once per ``key``."""
        key_b = key if budget_key is None else budget_key
        budget = used = self._budget(key_b, vertices, groups, classes)
        if key not in self._faces:  # not setdefault: its default would be copied to the device at every call
            self._faces[key] = jnp.asarray(groups)
        faces = self._faces[key]
        while True:
            *out, needed = run(faces, budget)
            have = np.atleast_1d(budget)
            need = np.asarray(needed).reshape(-1, len(have)).max(0)
            if (need <= have).all():
                lanes.note(self._budgets, key_b, used, budget)
                return out
            grown = tuple(_round_up(with_headroom(int(n), grown=True) + 1, self._small) if n > b else int(b)
                          for n, b in zip(need, have))
            budget = lanes.table(self._budgets)[key_b] = grown if classes is not None else grown[0]

    def _jitter(self, seed: int) -> np.ndarray:
        """Sample-grid jitter (n, H ss + W ss, 2) in [0, 1) for render ``seed``: each view's rows,
        then its columns (:func:`~ipm.render.edge_scan.spans`)."""
        n = (self.height + self.width) * self.ss
        return np.random.default_rng([int(seed), 7]).random((len(self.c2w), n, 2)).astype(np.float32)

    def render(self, vertices: np.ndarray, faces, seed: int = 0) -> np.ndarray:
        """Masks (n, height, width) in [0, 1] of a fixed mesh (no gradients). With G face groups
        (``faces`` a list of G; vertices (V, 3) shared or (G, V, 3) one set per group),
        (n, G, height, width): the silhouette and the mask of each further group where visible."""
        vertices = np.asarray(vertices, np.float32)
        jitter = self._jitter(seed)
        n_groups = _group_count(faces)
        if n_groups == 1:
            groups = _face_classes(faces)[0]
            v = jnp.asarray(vertices.reshape(-1, 3))
            masks, = self._run(("render", *_faces_key(groups)), groups, lambda: v, lambda f, budget: _render_fn(
                self.width, self.height, self.ss, budget)(v, f, self._w2c, self.focal, jitter))
            return np.asarray(masks, np.float32)
        blocks = n_groups if vertices.ndim == 3 and len(vertices) == n_groups else 1
        groups, classes = padded(*_face_classes(faces, vertices.shape[-2], blocks))
        v, cls = jnp.asarray(vertices.reshape(-1, 3)), jnp.asarray(classes)
        area, class_area = self._run(("render", *_faces_key(groups), *_class_sizes(classes)), groups, lambda: v,
                                     lambda f, budget: _class_render_fn(self.width, self.height, self.ss, budget,
                                                                        n_groups - 1, self.cull)(
                                         v, f, cls, self._w2c, self.focal, jitter), classes,
                                     ("render", len(groups), n_groups))
        return np.concatenate([np.asarray(area, np.float32)[:, None], np.asarray(class_area, np.float32)], 1)

    def loss_and_grad(self, vertex_fn: Callable, z: np.ndarray, faces, n_vertices: int,
                      targets: np.ndarray, seed: int = 0, highlight_targets: np.ndarray | None = None,
                      highlight_weight: float = 0.0, highlight_levels: int = 1,
                      highlight_loss: str = "mse") -> tuple[float, np.ndarray]:
        """Mean over views of the pixel MSE between rendered and target masks (plus, per further
        face group k, ``highlight_weight[k]`` times the ``highlight_loss`` of its masks against
        ``highlight_targets[:, k]``, ``"mse"`` or ``"dice"``, averaged over ``highlight_levels``
        levels of a 2 x 2 mean pyramid: :func:`pyramid_loss`), and d loss / d z. One further group
        may give its targets (n, H, W) and weight as a number. ``vertex_fn``: pure JAX z (m,) ->
        flattened world vertices, (3 V,) shared by the face groups or (G * 3 V,) one block per
        group (``n_vertices`` = V)."""
        highlight, n_groups = None, _group_count(faces)
        if n_groups > 1:
            if highlight_loss not in ("mse", "dice"):
                raise ValueError(f"unknown class-mask loss {highlight_loss!r} (known: mse, dice)")
            class_targets, weights = highlight_arrays(targets, n_groups - 1, highlight_targets, highlight_weight)
            highlight = (class_targets, weights, int(highlight_levels), highlight_loss)
        return self._call(vertex_fn, z, faces, targets, seed, n_vertices=n_vertices, highlight=highlight)

    def _call(self, vertex_fn, z, faces, targets, seed: int, n_vertices: int | None = None,
              highlight: tuple | None = None) -> tuple[float, np.ndarray]:
        """Loss and gradient (m,) at ``z`` (m,); ``highlight``: (class targets (n, K, H, W), weights
        (K,), levels, loss) of the K further face groups."""
        z = np.asarray(z, np.float32)  # numpy into the compiled calls: one transfer each, no eager ops
        targets = self._on_device(targets)
        jitter = self._jitter(seed)
        if highlight is not None:
            return self._class_call(vertex_fn, z, faces, targets, jitter, n_vertices, highlight)
        groups = _face_classes(faces)[0]
        program, constants, name = split(vertex_fn)

        def run(f, budget):
            return _loss_fn(program, name, self.width, self.height, self.ss, budget)(z, constants, f, targets,
                                                                                     self._w2c, self.focal, jitter)

        loss, grad = self._run((vertex_fn, *_faces_key(groups)), groups, lambda: vertex_fn(z), run)
        return float(loss), np.nan_to_num(np.asarray(grad, np.float64), nan=0.0, posinf=0.0, neginf=0.0).reshape(-1)

    def _on_device(self, array) -> jnp.ndarray:
        """``array`` (float32) on the device, copied once per array object a caller passes again
        and again (a search's target masks, at every step); the last few are kept."""
        with self._lock:  # tries side by side (``ipm.lanes``) share the copies
            if id(array) not in self._device:
                if len(self._device) >= 4:
                    self._device.clear()
                self._device[id(array)] = (array, jnp.asarray(np.asarray(array, np.float32)))  # holds it: ids stay
            return self._device[id(array)][1]

    def _class_call(self, vertex_fn, z, faces, targets, jitter, n_vertices: int, highlight: tuple):
        """:meth:`_call` with a class-mask term: the generator's vertices, the render program's loss
        and d loss / d vertices, then the generator's pullback."""
        if (vertex_fn, n_vertices) not in self._blocks:
            size = int(np.prod(jax.eval_shape(vertex_fn, z).shape))
            self._blocks[vertex_fn, n_vertices] = size // (3 * int(n_vertices))
        groups, classes = padded(*_face_classes(faces, n_vertices, self._blocks[vertex_fn, n_vertices]))
        key = ("class", *_faces_key(groups), *_class_sizes(classes))
        if key not in self._classes:
            self._classes[key] = jnp.asarray(classes)
        cls, class_targets = self._classes[key], self._on_device(highlight[0])
        program, constants, name = split(vertex_fn)
        vertices = vertex_fn(z)
        loss, dv = self._run(key, groups, lambda: vertices, lambda f, budget: _class_loss_fn(
            self.width, self.height, self.ss, budget, tuple(highlight[1:]), self.cull)(
            vertices, f, cls, targets, class_targets, self._w2c, self.focal, jitter), classes,
            ("class", len(groups), len(highlight[1])))
        grad = np.asarray(_pullback(program, name)(z, constants, dv), np.float64)
        return float(loss), np.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)
