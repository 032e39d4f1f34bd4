"""Sparse points to a surface: normals oriented towards the observing cameras, screened Poisson
(open3d), trim of the low-density vertices, optional crop to a box. All in the world frame."""
from __future__ import annotations

import numpy as np


class MeshingError(RuntimeError):
    """Poisson produced no usable surface (too few or degenerate points)."""


def oriented_normals(points: np.ndarray, view_dirs: np.ndarray, k: int = 16) -> np.ndarray:
    """Unit normals of ``points`` from PCA of ``k`` nearest neighbours (open3d), each flipped
    to face ``view_dirs`` (the mean unit direction from the point to its observing cameras)."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=min(k, len(points) - 1)))
    n = np.asarray(pcd.normals).copy()
    flip = (n * view_dirs).sum(1) < 0
    n[flip] *= -1
    return n


def poisson_mesh(points: np.ndarray, normals: np.ndarray, depth: int = 7, trim: float = 0.05,
                 box: tuple[np.ndarray, np.ndarray] | None = None, seed: int = 0,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Screened Poisson surface of oriented points (one thread), without its lowest-density
    ``trim`` share of vertices and, given ``box = (lo, hi)``, without vertices outside the box.
    Returns (vertices (n, 3), faces (m, 3)); raises ``MeshingError`` if nothing is left."""
    import open3d as o3d

    o3d.utility.random.seed(int(seed))
    if len(points) < 20:
        raise MeshingError(f"too few points for Poisson ({len(points)})")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    pcd.normals = o3d.utility.Vector3dVector(np.asarray(normals, np.float64))
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pcd, depth=int(depth), n_threads=1)
    density = np.asarray(density)
    if len(mesh.triangles) == 0 or len(density) == 0:
        raise MeshingError("Poisson returned an empty surface")
    drop = density < np.quantile(density, trim) if trim > 0 else np.zeros(len(density), bool)
    if box is not None:
        v = np.asarray(mesh.vertices)
        lo, hi = box
        drop |= np.any((v < lo) | (v > hi), axis=1)
    mesh.remove_vertices_by_mask(drop)
    mesh.remove_unreferenced_vertices()
    verts, faces = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    if len(faces) == 0 or not np.all(np.isfinite(verts)):
        raise MeshingError("nothing left of the Poisson surface after trimming")
    return verts.copy(), faces.astype(np.int64)
