"""Visual hull: space carving of a voxel grid by the masks of known cameras, then marching cubes.

The classical mask-only baseline the paper omits. A cell's occupancy is the smallest bilinear
mask value over the views, so the surface sits on the silhouette cones' boundary at level 0.5.
"""
from __future__ import annotations

import numpy as np
from tqdm import tqdm

from baselines.common import begin, extract_surface, write_result
from ipm.hull import grid_points, mask_values

GRID = {"smoke": 48, "default": 128, "paper": 256}
"""Voxels per axis of the carved grid, per profile."""


def carve(views, lo: np.ndarray, hi: np.ndarray, n: int, progress: bool = False, chunk: int = 1 << 18) -> np.ndarray:
    """Occupancy grid (n, n, n): the minimum over views of the mask value at each cell centre."""
    pts = grid_points(lo, hi, n)
    occ = np.empty(len(pts), np.float32)
    for s in tqdm(range(0, len(pts), chunk), desc="carve", disable=not progress, leave=False):
        occ[s:s + chunk] = mask_values(views, pts[s:s + chunk]).min(0)
    return occ.reshape(n, n, n)


def run_visual_hull(views_path, out, profile: str = "default", seed: int = 0, progress: bool = True,
                    n_input_views: int | None = None, **_) -> dict:
    """``ipm baseline visual_hull``: OUT/mesh.ply (world frame), timing.json, info.json."""
    grid, t0, _, views, lo, hi = begin(GRID, profile, views_path, n_input_views)
    occ = carve(views, lo, hi, grid, progress)
    verts, faces = extract_surface(occ, lo, hi, 0.5, inside_positive=True)
    info = {"method": "visual_hull", "views": len(views), "grid": grid, "box": [lo.tolist(), hi.tolist()]}
    return write_result(out, verts, faces, t0, info)
