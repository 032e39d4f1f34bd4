"""What the baselines share: input views, the working volume, mask carving, marching cubes and
the atomic write of the result."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import trimesh

from ipm.errors import UserError
from ipm.io import atomic_dir, load_views, save_ply, write_json
from ipm.io.views import Views
from ipm.render.cameras import project


def input_views(views_path: str | Path, n_input_views: int | None, minimum: int = 2) -> Views:
    """The first ``n_input_views`` views of ``views_path`` (all if None); at least ``minimum``."""
    return load_views(views_path).first(n_input_views, minimum)


def mask_values(views: Views, points: np.ndarray) -> np.ndarray:
    """Bilinear mask value of each point in each view, shape (n_views, n_points); 0 outside the image."""
    out = np.zeros((len(views), len(points)), np.float32)
    for i, (mask, c2w) in enumerate(zip(views.masks, views.c2w)):
        xy = project(points, c2w, views.fov_x, views.width, views.height) - 0.5
        x0, y0 = np.floor(xy[:, 0]).astype(int), np.floor(xy[:, 1]).astype(int)
        fx, fy = xy[:, 0] - x0, xy[:, 1] - y0
        padded = np.pad(mask, 1)
        xi = np.clip(x0 + 1, 0, views.width)
        yi = np.clip(y0 + 1, 0, views.height)
        inside = (x0 >= -1) & (x0 < views.width) & (y0 >= -1) & (y0 < views.height)
        v = (padded[yi, xi] * (1 - fx) * (1 - fy) + padded[yi, xi + 1] * fx * (1 - fy)
             + padded[yi + 1, xi] * (1 - fx) * fy + padded[yi + 1, xi + 1] * fx * fy)
        out[i] = np.where(inside, v, 0.0)
    return out


def grid_points(lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """Cell-centre points of an ``n``^3 grid over the box [lo, hi], x-major, shape (n^3, 3)."""
    axes = [lo[k] + (np.arange(n) + 0.5) * (hi[k] - lo[k]) / n for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def object_box(views: Views, n: int = 48, pad: float = 0.08) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box around the object: the point nearest to all optical axes, a cube that
    every camera's frustum covers, carved coarsely by the masks, then padded."""
    eyes, dirs = views.c2w[:, :3, 3], -views.c2w[:, :3, 2]
    a = sum(np.eye(3) - np.outer(d, d) for d in dirs)
    b = sum((np.eye(3) - np.outer(d, d)) @ e for d, e in zip(dirs, eyes))
    centre = np.linalg.lstsq(a, b, rcond=None)[0]
    half = min(np.linalg.norm(eyes - centre, axis=1)) * np.tan(0.5 * views.fov_x)
    lo, hi = centre - half, centre + half
    pts = grid_points(lo, hi, n)
    keep = mask_values(views, pts).min(0) > 0.5
    if not keep.any():
        raise UserError("the masks share no common volume: are the cameras consistent with the masks?")
    cell = (hi - lo) / n
    inner_lo, inner_hi = pts[keep].min(0) - cell, pts[keep].max(0) + cell
    margin = pad * (inner_hi - inner_lo).max()
    return inner_lo - margin, inner_hi + margin


def extract_surface(field: np.ndarray, lo: np.ndarray, hi: np.ndarray, level: float,
                    inside_positive: bool) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes (scikit-image) of a cell-centred grid ``field`` over [lo, hi] at ``level``:
    world vertices and outward-facing triangles. The grid is padded so the surface closes."""
    from skimage.measure import marching_cubes

    if not (field.min() < level < field.max()):
        raise UserError("no surface: the field never crosses its level (empty or full volume)")
    outside = field.min() - 1.0 if inside_positive else field.max() + 1.0
    f = np.pad(field, 1, constant_values=outside)
    n = np.array(field.shape)
    spacing = (hi - lo) / n
    verts, faces, _, _ = marching_cubes(f, level, spacing=tuple(spacing))
    verts += lo - 0.5 * spacing  # padded index i is the centre of cell i - 1: lo + (i - 0.5) spacing
    faces = np.ascontiguousarray(faces)
    if trimesh.Trimesh(verts, faces, process=False).volume < 0:  # outward winding
        faces = np.ascontiguousarray(faces[:, ::-1])
    return verts, faces


def write_result(out: str | Path, vertices: np.ndarray, faces: np.ndarray, t0: float, info: dict,
                 extra_files: dict | None = None) -> dict:
    """OUT/mesh.ply, OUT/timing.json and OUT/info.json, atomically; returns ``info`` with the time."""
    if len(faces) == 0 or not np.all(np.isfinite(vertices)):
        raise FloatingPointError("the baseline produced an empty or non-finite mesh")
    info = {**info, "seconds": time.perf_counter() - t0}
    with atomic_dir(out) as tmp:
        save_ply(tmp / "mesh.ply", vertices, faces)
        write_json(tmp / "timing.json", {"seconds": info["seconds"]})
        write_json(tmp / "info.json", info)
        for name, write in (extra_files or {}).items():
            write(tmp / name)
    return info


def write_failure(out: str | Path, t0: float, info: dict, reason: str) -> dict:
    """Record a run that produced no mesh (too few registered images, no points): an empty
    OUT/mesh.ply and ``failed`` in OUT/info.json, so the table shows "-" with the reason and
    the pipeline goes on, as the paper's table does."""
    info = {**info, "failed": reason, "seconds": time.perf_counter() - t0}
    with atomic_dir(out) as tmp:
        save_ply(tmp / "mesh.ply", np.zeros((0, 3)), np.zeros((0, 3), np.int64))
        write_json(tmp / "timing.json", {"seconds": info["seconds"], "failed": reason})
        write_json(tmp / "info.json", info)
    return info
