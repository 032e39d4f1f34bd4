"""Reference lines of the table, computed from the reference mesh itself (not reconstructions).

Silhouette IoU has a small range (DESIGN.md): the reference's convex hull and its bounding
sphere show where "shape-agnostic" answers already land, so method rows can be read against them.
"""
from __future__ import annotations

import time

import numpy as np
import trimesh

from ipm.registry import Registry

REFERENCE_LINES: Registry = Registry("reference line")


@REFERENCE_LINES.register("convex_hull")
def convex_hull(reference: trimesh.Trimesh) -> trimesh.Trimesh:
    """The convex hull of the reference (fills the cup's cavity and the handle's hole)."""
    return reference.convex_hull


@REFERENCE_LINES.register("bounding_sphere")
def bounding_sphere(reference: trimesh.Trimesh) -> trimesh.Trimesh:
    """The sphere around the reference's bounding-box centre through its farthest vertex."""
    lo, hi = reference.bounds
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(reference.vertices - centre, axis=1).max())
    return trimesh.creation.icosphere(subdivisions=4, radius=radius).apply_translation(centre)


def write_reference_line(name: str, reference: str, out: str) -> None:
    """``ipm reference-line``: OUT/mesh.ply and OUT/timing.json for line ``name``, atomically."""
    from ipm.io import atomic_dir, load_mesh, save_ply, write_json

    make = REFERENCE_LINES[name]
    t0 = time.perf_counter()
    mesh = make(load_mesh(reference))
    with atomic_dir(out) as tmp:
        save_ply(tmp / "mesh.ply", mesh.vertices, mesh.faces)
        write_json(tmp / "timing.json", {"seconds": time.perf_counter() - t0})
