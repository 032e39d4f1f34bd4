"""First hits of camera rays on a mesh by Mitsuba's ray casts: depth and face per pixel.

The variant is the process's (``ipm.runtime.set_mitsuba_variant``)."""
from __future__ import annotations

import numpy as np


def mesh_scene(vertices: np.ndarray, faces: np.ndarray):
    """A Mitsuba scene of one mesh (vertices (V, 3), faces (F, 3)) alone, for ray casts."""
    import mitsuba as mi

    from ipm.render.textured import set_mesh_buffers

    mesh = mi.Mesh("fit", len(vertices), len(faces))
    set_mesh_buffers(mesh, vertices, faces)
    return mi.load_dict({"type": "scene", "fit": mesh})


def pixel_hits(scene, c2w: np.ndarray, fov_x: float, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Distance along each pixel centre's ray (height, width; inf where it misses) and the face it
    meets first (-1 where none), for the pinhole camera ``c2w`` (OpenGL, 4x4) of horizontal field
    of view ``fov_x`` (radians)."""
    import mitsuba as mi

    focal = 0.5 * width / np.tan(0.5 * fov_x)
    x, y = np.meshgrid(np.arange(width) + 0.5 - 0.5 * width, 0.5 * height - np.arange(height) - 0.5)
    d = np.stack([x / focal, y / focal, -np.ones_like(x)], -1).reshape(-1, 3) @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(c2w[:3, 3], d.shape)
    ray = mi.Ray3f(mi.Point3f(*(o[:, i].astype(np.float32) for i in range(3))),
                   mi.Vector3f(*(d[:, i].astype(np.float32) for i in range(3))))
    si = scene.ray_intersect(ray)
    t = np.array(si.t, np.float64)
    hit = np.isfinite(t)
    face = np.where(hit, np.array(si.prim_index, np.int64), -1)
    return np.where(hit, t, np.inf).reshape(height, width), face.reshape(height, width)
