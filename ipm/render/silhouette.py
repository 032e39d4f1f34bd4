"""Differentiable silhouettes with Mitsuba 3 (``docs/design``, "Silhouette rendering").

The mesh is an area emitter of radiance 1 and there is no other light, so the rendered
image is the mask (pixel coverage). With further face groups (a building's windows, its roof)
the mesh is one emitter per group, (1, 0, 0), (1, 1, 0) and (1, 0, 1): red is the silhouette,
green and blue the visible parts of the second and third groups (their masks), all edges of
meshes, so all differentiate. Each group may have
its own vertex block (a generator with shared positions keeps every face in both groups and moves
each group's other vertices to a point, so one scene serves every topology). ``direct_projective`` with ``sppi = 0`` differentiates
the visibility discontinuities at silhouette edges. Vertex positions come from a JAX
function wrapped with ``drjit.wrap``, so gradients reach generator and pose parameters
without hand-written chain rules.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ipm.errors import UserError
from ipm.render.cameras import sensor_dict

GROUPS = (("object", [1.0, 0.0, 0.0]), ("highlight", [1.0, 1.0, 0.0]), ("highlight2", [1.0, 0.0, 1.0]))
"""Each face group's emitter: its name in the scene and its colour (the channel of its mask)."""

MAX_GROUPS = 3
"""Face groups a renderer draws at most: the silhouette and two class masks (the colour channels
of :data:`GROUPS`; ``ipm.render.edges`` keeps the same bound)."""


def group_count(faces) -> int:
    """How many face groups ``faces`` holds (an array is one; a list, one per entry); more than
    :data:`MAX_GROUPS` are refused."""
    n = len(faces) if isinstance(faces, (list, tuple)) else 1
    if n > MAX_GROUPS:
        raise UserError(f"the renderers draw a silhouette and at most {MAX_GROUPS - 1} class masks, not {n - 1}")
    return n


def highlight_arrays(targets, n_classes: int, highlight_targets, highlight_weight) -> tuple[np.ndarray, tuple]:
    """The class targets (n, K, H, W) and weights (K,) of ``n_classes`` further face groups from a
    renderer's ``highlight_targets`` ((n, H, W) for one class, (n, K, H, W); None: empty masks) and
    ``highlight_weight`` (a number for one class, or K numbers)."""
    targets = np.asarray(targets, np.float32)
    if highlight_targets is None:
        highlight_targets = np.zeros((len(targets), n_classes, *targets.shape[1:]), np.float32)
    highlight_targets = np.asarray(highlight_targets, np.float32)
    if highlight_targets.ndim == 3:
        highlight_targets = highlight_targets[:, None]
    weights = tuple(float(w) for w in np.atleast_1d(highlight_weight))
    if highlight_targets.shape != (len(targets), n_classes, *targets.shape[1:]) or len(weights) != n_classes:
        raise ValueError(f"{n_classes} class masks need targets of shape {(len(targets), n_classes, *targets.shape[1:])}"
                         f" and {n_classes} weights, not {highlight_targets.shape} and {len(weights)}")
    return highlight_targets, weights


class SilhouetteRenderer:
    """Renders masks of one triangle mesh seen by a fixed set of cameras.

    Parameters
    ----------
    c2w : (n, 4, 4) OpenGL camera-to-world matrices.
    fov_x : horizontal field of view in radians.
    width, height : image size in pixels.
    spp : samples per pixel.
    """

    def __init__(self, c2w: np.ndarray, fov_x: float, width: int, height: int, spp: int = 4):
        self.c2w, self.fov_x, self.width, self.height, self.spp = np.asarray(c2w), fov_x, width, height, spp
        self._scenes: dict = {}
        self._wrapped: dict = {}

    def _scene(self, groups: list[np.ndarray], n_vertices: int):
        """A scene (one mesh emitter per face group + one sensor per view) for these faces, built
        once, group g emitting :data:`GROUPS`' g-th colour."""
        key = (n_vertices, tuple((g.shape, g[:16].tobytes(), g[-16:].tobytes()) for g in groups))
        if key not in self._scenes:
            import mitsuba as mi

            scene = {"type": "scene", "integrator": {"type": "direct_projective", "sppi": 0}}
            names = []
            for (name, colour), sel in zip(GROUPS, groups):
                if not len(sel):
                    continue
                props = mi.Properties()
                props["emitter"] = mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": colour}})
                mesh = mi.Mesh(name, n_vertices, len(sel), props=props)
                mp = mi.traverse(mesh)
                mp["faces"] = mi.UInt32(np.ascontiguousarray(sel, np.uint32).ravel())
                mp["vertex_positions"] = mi.Float(np.zeros(3 * n_vertices, np.float32))
                mp.update()
                scene[name] = mesh
                names.append(name)
            for i, m in enumerate(self.c2w):
                scene[f"sensor_{i:03d}"] = sensor_dict(m, self.fov_x, self.width, self.height)
            scene = mi.load_dict(scene)
            self._scenes[key] = (scene, mi.traverse(scene), names)
        return self._scenes[key]

    def render(self, vertices: np.ndarray, faces, seed: int = 0) -> np.ndarray:
        """Masks (n, height, width) in [0, 1] of a fixed mesh (no gradients). With G face groups
        (``faces`` a list of G; vertices (V, 3) shared or (G, V, 3) one set per group),
        (n, G, height, width): the silhouette and the mask of each further group where visible."""
        import mitsuba as mi

        groups = _face_groups(faces)
        vertices = np.asarray(vertices, np.float32)
        blocks = list(vertices) if len(vertices) == len(groups) and vertices.ndim == 3 else [vertices.reshape(-1, 3)] * len(groups)
        scene, params, names = self._scene(groups, len(blocks[0]))
        for (name, _), block in zip(GROUPS, blocks):
            if name in names:
                params[f"{name}.vertex_positions"] = mi.Float(block.ravel())
        params.update()
        out = [np.array(mi.render(scene, sensor=i, spp=self.spp, seed=seed))[..., : len(groups)]
               for i in range(len(self.c2w))]
        out = np.clip(np.stack(out), 0.0, 1.0)
        return out[..., 0] if len(groups) == 1 else np.moveaxis(out, -1, 1)

    def loss_and_grad(self, vertex_fn: Callable, z: np.ndarray, faces, n_vertices: int,
                      targets: np.ndarray, seed: int = 0, highlight_targets: np.ndarray | None = None,
                      highlight_weight: float = 0.0, highlight_levels: int = 1,
                      highlight_loss: str = "mse") -> tuple[float, np.ndarray]:
        """Mean over views of the pixel MSE between rendered and target masks (plus, per further
        face group k, ``highlight_weight[k]`` times the ``highlight_loss`` of its masks against
        ``highlight_targets[:, k]``, ``"mse"`` or ``"dice"``, averaged over ``highlight_levels``
        levels of a 2x2 mean pyramid: :func:`_pyramid_loss`), and d loss / d z. One further group
        may give its targets (n, H, W) and weight as a number.

        ``vertex_fn`` is a pure JAX function z (m,) -> flattened world vertices: (3 V,) shared by
        the face groups, or (G * 3 V,) one block per group (``n_vertices`` = V). ``faces``: one
        array, or a list of face groups (the masks of all but the first are highlights).
        """
        import drjit as dr
        import mitsuba as mi

        wrapped = self._wrapped.get(vertex_fn)
        if wrapped is None:
            wrapped = dr.wrap(source="drjit", target="jax")(vertex_fn)
            self._wrapped[vertex_fn] = wrapped
        groups = _face_groups(faces)
        if len(groups) > 1:
            highlight_targets, weights = highlight_arrays(targets, len(groups) - 1, highlight_targets,
                                                          highlight_weight)
        scene, params, names = self._scene(groups, n_vertices)
        zt = mi.TensorXf(np.asarray(z, np.float32))
        dr.enable_grad(zt)
        verts = wrapped(zt).array
        blocks = dr.width(verts) // (3 * n_vertices)
        for g, (name, _) in enumerate(GROUPS[: len(groups)]):
            if name in names:
                params[f"{name}.vertex_positions"] = verts if blocks == 1 else dr.gather(
                    mi.Float, verts, dr.arange(mi.UInt32, 3 * n_vertices) + 3 * n_vertices * g)
        params.update()
        loss = 0.0
        n = len(self.c2w)
        for i in range(n):
            img = mi.render(scene, params, sensor=i, spp=self.spp, seed=seed * n + i)
            ref = mi.TensorXf(np.asarray(targets[i], np.float32)[..., None])
            loss = loss + dr.mean(dr.square(img[..., 0:1] - ref), axis=None) / n
            for k, weight in enumerate(weights if len(groups) > 1 else (), start=1):
                if weight > 0:
                    loss = loss + weight * _pyramid_loss(img[..., k:k + 1].array, highlight_targets[i, k - 1],
                                                         highlight_levels, highlight_loss) / n
        dr.backward(loss)
        grad = np.array(dr.grad(zt), np.float64)
        value = float(np.array(loss.array if hasattr(loss, "array") else loss).ravel()[0])
        return value, np.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)


def _face_groups(faces) -> list[np.ndarray]:
    """``faces`` as a list of face groups (one array is one group; at most three)."""
    group_count(faces)
    return [np.asarray(f) for f in faces] if isinstance(faces, (list, tuple)) else [np.asarray(faces)]


def _pyramid_loss(image, target: np.ndarray, levels: int, kind: str = "mse"):
    """Mean over ``levels`` levels of a 2 x 2 mean pyramid of a loss between ``image`` (a flat
    Dr.Jit array of ``target``'s shape) and ``target``: ``"mse"``, or ``"dice"`` (1 - 2 |a b| /
    (|a| + |b|), 0 where neither has the class). The coarse levels compare how much of each region
    the class covers, so a misplaced window is pulled towards the target's windows. With the MSE a
    window that misses costs more than none, so a search can hide the windows (building_d2, dev);
    the Dice term scores a miss like no window at all, and any overlap better."""
    import drjit as dr
    import mitsuba as mi

    if kind not in ("mse", "dice"):
        raise ValueError(f"unknown class-mask loss {kind!r} (known: mse, dice)")

    def term(a, b):
        if kind == "mse":
            return dr.mean(dr.square(a - b), axis=None)
        return 1.0 - (2.0 * dr.mean(a * b, axis=None) + 1e-6) / (dr.mean(a, axis=None) + dr.mean(b, axis=None) + 1e-6)

    target = np.asarray(target, np.float32)
    h, w = target.shape
    errors = []
    for level in range(levels):
        errors.append(term(image, mi.Float(target.ravel())))
        if level == levels - 1 or min(h, w) < 2:
            break
        h2, w2 = h // 2, w // 2
        idx = dr.arange(mi.UInt32, h2 * w2)
        y = idx // w2
        base = 2 * y * w + 2 * (idx - y * w2)
        image = 0.25 * (dr.gather(mi.Float, image, base) + dr.gather(mi.Float, image, base + 1)
                        + dr.gather(mi.Float, image, base + w) + dr.gather(mi.Float, image, base + w + 1))
        target = target[: 2 * h2, : 2 * w2].reshape(h2, 2, w2, 2).mean((1, 3))
        h, w = h2, w2
    return sum(errors[1:], errors[0]) / len(errors)
