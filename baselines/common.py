"""What the baselines share: input views, marching cubes and the atomic write of the result (the
working volume and mask carving: ``ipm.hull``)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import trimesh

from ipm.errors import UserError
from ipm.hull import object_box
from ipm.io import load_views
from ipm.io.views import Views
from ipm.methods.results import write_result as write_folder


def input_views(views_path: str | Path, n_input_views: int | None, minimum: int = 2) -> Views:
    """The first ``n_input_views`` views of ``views_path`` (all if None); at least ``minimum``."""
    return load_views(views_path).first(n_input_views, minimum)


def begin(profiles: dict, profile: str, views_path, n_input_views: int | None):
    """What a volumetric baseline starts from: its named profile (``UserError`` naming the known
    ones), the start's wall and CPU clocks, the input views and the object box around them."""
    if profile not in profiles:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(profiles)})")
    t0, cpu0 = time.perf_counter(), time.process_time()
    views = input_views(views_path, n_input_views)
    lo, hi = object_box(views)
    return profiles[profile], t0, cpu0, views, lo, hi


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
    """OUT/mesh.ply, OUT/timing.json and OUT/info.json (``ipm.methods.results``); returns ``info`` with the time."""
    info = {**info, "seconds": time.perf_counter() - t0}
    return write_folder(out, (vertices, faces), info, {"seconds": info["seconds"]}, info_file="info.json",
                        extra_files=extra_files)


def write_failure(out: str | Path, t0: float, info: dict, reason: str) -> dict:
    """Record a run that produced no mesh (too few registered images, no points): an empty
    OUT/mesh.ply and ``failed`` in OUT/info.json, so the table shows "-" with the reason and
    the pipeline goes on, as the paper's table does."""
    info = {**info, "failed": reason, "seconds": time.perf_counter() - t0}
    return write_folder(out, (np.zeros((0, 3)), np.zeros((0, 3), np.int64)), info,
                        {"seconds": info["seconds"], "failed": reason}, info_file="info.json", failed=True)
