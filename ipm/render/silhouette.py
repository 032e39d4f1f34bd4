"""Differentiable silhouettes with Mitsuba 3 (DESIGN.md, "Silhouette rendering").

The mesh is an area emitter of radiance 1 and there is no other light, so the rendered
image is the mask (pixel coverage). With ``highlight`` (a face subset, a building's windows) the
mesh is split in two emitters, (1, 0, 0) and (1, 1, 0): red is the silhouette and green the
visible part of the subset (its mask), both edges of meshes, so both differentiate. ``direct_projective`` with ``sppi = 0`` differentiates
the visibility discontinuities at silhouette edges. Vertex positions come from a JAX
function wrapped with ``drjit.wrap``, so gradients reach generator and pose parameters
without hand-written chain rules.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ipm.render.cameras import sensor_dict


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

    def _scene(self, faces: np.ndarray, n_vertices: int, highlight: np.ndarray | None = None):
        """A scene (mesh emitters + one sensor per view) for this topology, built once."""
        mark = None if highlight is None else np.packbits(highlight).tobytes()
        key = (n_vertices, faces.shape, faces[:16].tobytes(), faces[-16:].tobytes(), mark)
        if key not in self._scenes:
            import mitsuba as mi

            if highlight is None:
                groups = {"object": (faces, [1.0, 1.0, 1.0])}
            else:
                groups = {"object": (faces[~highlight], [1.0, 0.0, 0.0]), "highlight": (faces[highlight], [1.0, 1.0, 0.0])}
            scene = {"type": "scene", "integrator": {"type": "direct_projective", "sppi": 0}}
            for name, (sel, colour) in groups.items():
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
            for i, m in enumerate(self.c2w):
                scene[f"sensor_{i:03d}"] = sensor_dict(m, self.fov_x, self.width, self.height)
            scene = mi.load_dict(scene)
            self._scenes[key] = (scene, mi.traverse(scene), [name for name, (sel, _) in groups.items() if len(sel)])
        return self._scenes[key]

    def render(self, vertices: np.ndarray, faces: np.ndarray, seed: int = 0,
               highlight: np.ndarray | None = None) -> np.ndarray:
        """Masks (n, height, width) in [0, 1] of a fixed mesh (no gradients); with ``highlight``
        (bool per face), (n, 2, height, width): the silhouette and the highlighted faces' mask."""
        import mitsuba as mi

        scene, params, meshes = self._scene(faces, len(vertices), highlight)
        for name in meshes:
            params[f"{name}.vertex_positions"] = mi.Float(np.asarray(vertices, np.float32).ravel())
        params.update()
        out = [np.array(mi.render(scene, sensor=i, spp=self.spp, seed=seed))[..., :2]
               for i in range(len(self.c2w))]
        out = np.clip(np.stack(out), 0.0, 1.0)
        return out[..., 0] if highlight is None else np.moveaxis(out, -1, 1)

    def loss_and_grad(self, vertex_fn: Callable, z: np.ndarray, faces: np.ndarray, n_vertices: int,
                      targets: np.ndarray, seed: int = 0, highlight: np.ndarray | None = None,
                      highlight_targets: np.ndarray | None = None,
                      highlight_weight: float = 0.0) -> tuple[float, np.ndarray]:
        """Mean over views of the pixel MSE between rendered and target masks (plus
        ``highlight_weight`` times that of the highlighted faces' masks), and d loss / d z.

        ``vertex_fn`` is a pure JAX function z (m,) -> flattened world vertices (3 V,).
        """
        import drjit as dr
        import mitsuba as mi

        wrapped = self._wrapped.get(vertex_fn)
        if wrapped is None:
            wrapped = dr.wrap(source="drjit", target="jax")(vertex_fn)
            self._wrapped[vertex_fn] = wrapped
        scene, params, meshes = self._scene(faces, n_vertices, highlight)
        zt = mi.TensorXf(np.asarray(z, np.float32))
        dr.enable_grad(zt)
        verts = wrapped(zt)
        for name in meshes:
            params[f"{name}.vertex_positions"] = verts.array
        params.update()
        loss = 0.0
        n = len(self.c2w)
        for i in range(n):
            img = mi.render(scene, params, sensor=i, spp=self.spp, seed=seed * n + i)
            ref = mi.TensorXf(np.asarray(targets[i], np.float32)[..., None])
            loss = loss + dr.mean(dr.square(img[..., 0:1] - ref), axis=None) / n
            if highlight is not None and highlight_weight > 0:
                ref2 = mi.TensorXf(np.asarray(highlight_targets[i], np.float32)[..., None])
                loss = loss + highlight_weight * dr.mean(dr.square(img[..., 1:2] - ref2), axis=None) / n
        dr.backward(loss)
        grad = np.array(dr.grad(zt), np.float64)
        value = float(np.array(loss.array if hasattr(loss, "array") else loss).ravel()[0])
        return value, np.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)
