"""Reference lines of the table, computed from the reference itself (not reconstructions).

Silhouette IoU has a small range (``docs/design``, "The metric"): the reference's convex hull
and its bounding sphere show where "shape-agnostic" answers already land, so method rows can be
read against them.
For in-family cases of a stochastic generator (trees place leaves by their own random stream),
``reseeded_truth`` is the truth's parameters and pose with another seed: what a fit that recovers
every parameter but the random stream would score.
"""
from __future__ import annotations

import time

from typing import TYPE_CHECKING

import numpy as np

from ipm.errors import UserError
from ipm.registry import Registry

if TYPE_CHECKING:  # trimesh is loaded where a line runs, not where the workflow reads the names
    import trimesh

REFERENCE_LINES: Registry = Registry("reference line")


def line(name: str, label: str, applies=None):
    """Register a line ``fn(reference, case) -> Trimesh`` under ``name`` with its table ``label``.
    A line given ``applies(case) -> bool`` needs the case definition and runs only where it applies."""

    def deco(fn):
        fn.label, fn.needs_case = label, applies is not None
        fn.applies = applies or (lambda case: True)
        return REFERENCE_LINES.register(name)(fn)

    return deco


@line("convex_hull", "convex hull (reference)")
def convex_hull(reference: trimesh.Trimesh, case: dict | None = None) -> trimesh.Trimesh:
    """The convex hull of the reference (fills the cup's cavity and the handle's hole)."""
    return reference.convex_hull


@line("bounding_sphere", "bounding sphere (reference)")
def bounding_sphere(reference: trimesh.Trimesh, case: dict | None = None) -> trimesh.Trimesh:
    """The sphere around the reference's bounding-box centre through its farthest vertex."""
    import trimesh

    lo, hi = reference.bounds
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(reference.vertices - centre, axis=1).max())
    return trimesh.creation.icosphere(subdivisions=4, radius=radius).apply_translation(centre)


def _reseedable(case: dict) -> bool:
    """In-family cases whose generator has a random stream (a ``seed`` parameter)."""
    from ipm.generators import get_generator

    src = case.get("source", {})
    return "generator" in src and "seed" in get_generator(src["generator"]).spec.index


@line("reseeded_truth", "true parameters, other seed (reference)", applies=_reseedable)
def reseeded_truth(reference: trimesh.Trimesh, case: dict | None = None) -> trimesh.Trimesh:
    """The case's true parameters and pose with the next value of the generator's ``seed``."""
    import trimesh

    from ipm.generators import get_generator
    from ipm.synth import ground_truth_mesh

    if case is None or not _reseedable(case):
        raise UserError("reseeded_truth needs an in-family case of a generator with a seed parameter")
    src = case["source"]
    gen = get_generator(src["generator"])
    base = gen.presets[src["preset"]] if "preset" in src else None
    seed = int(gen.spec.from_dict(src.get("params", {}), base)[gen.spec.index["seed"]])
    hi = int(gen.spec.upper[gen.spec.index["seed"]])
    other = {**case, "source": {**src, "params": {**src.get("params", {}), "seed": (seed + 1) % (hi + 1)}}}
    v, f, _, _ = ground_truth_mesh(other)
    return trimesh.Trimesh(v, f, process=False)


def write_reference_line(name: str, reference: str, out: str, truth: str | None = None) -> None:
    """``ipm reference-line``: OUT/mesh.ply and OUT/timing.json for line ``name``, atomically;
    ``truth`` is the case's ground_truth.json, for the lines that need the case."""
    import json
    from pathlib import Path

    from ipm.io import atomic_dir, load_mesh, save_ply, write_json

    make = REFERENCE_LINES[name]
    case = None
    if make.needs_case:
        if truth is None or not Path(truth).is_file():
            raise UserError(f"reference line {name!r} needs the case's ground_truth.json (--truth), got {truth}")
        case = json.loads(Path(truth).read_text())
        if not make.applies(case):
            raise UserError(f"reference line {name!r} does not apply to case {case.get('name')!r}")
    t0 = time.perf_counter()
    mesh = make(load_mesh(reference), case)
    with atomic_dir(out) as tmp:
        save_ply(tmp / "mesh.ply", mesh.vertices, mesh.faces)
        write_json(tmp / "timing.json", {"seconds": time.perf_counter() - t0})
