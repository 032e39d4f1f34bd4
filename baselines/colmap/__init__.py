"""COLMAP baselines (pycolmap 4.x on the CPU, one thread): sparse reconstruction, then a
screened Poisson surface (open3d) of the sparse points.

- ``colmap_known``: SIFT on the textured rgb views, exhaustive matching, triangulation at the
  known camera poses of transforms.json (two-view tracks kept, poses fixed).
- ``colmap_sfm``: the same features and matches, pose-free incremental SfM (two-view tracks
  kept as well), then the model is brought into the world frame by the similarity that maps
  its camera centres onto the known ones (Umeyama over the registered images, matched by image
  name, misregistered cameras dropped as outliers).

Both use the known pinhole intrinsics (focal length from camera_angle_x, principal point at
the image centre) and keep them fixed; one shared camera.

Both mesh the points the same way: normals from nearest neighbours oriented towards the
cameras that observe each point, Poisson at depth ~7, the lowest-density 5 % of vertices
trimmed, points and mesh cropped to the object box of the masks (``object_box``).

Dense MVS (``patch_match_stereo``) is not run: the pycolmap wheel is built without CUDA and
COLMAP's dense stereo requires it, so these are sparse-point baselines (info.json says so).

A run that cannot produce a mesh (too few registered images or points, Poisson failure, a
COLMAP error) writes an empty mesh and ``failed`` in info.json instead of raising; bad input
(missing images, unknown profile) raises ``UserError``.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from baselines.colmap.geometry import apply_similarity, robust_umeyama
from baselines.colmap.meshing import MeshingError, oriented_normals, poisson_mesh
from baselines.colmap.pipeline import (extract, incremental_sfm, make_workspace, match,
                                       points_and_observers, quiet_colmap, triangulate_known)
from baselines.common import input_views, write_failure, write_result
from ipm.hull import object_box
from ipm.errors import UserError

PROFILES = {
    "smoke": {"max_features": 1024, "first_octave": 0, "poisson_depth": 6},
    "default": {"max_features": 2048, "first_octave": -1, "poisson_depth": 7},
    "paper": {"max_features": 8192, "first_octave": -1, "poisson_depth": 8},
}
"""Per profile: SIFT features per image, SIFT's first octave (-1, COLMAP's default, upsamples the
image twice for small-scale features; 0 is about 4x faster with about a third of the points)
and the Poisson octree depth. The 512 px renders give about 1000 SIFT keypoints per image at
octave -1, under every cap here."""

TRIM = 0.05
"""Share of lowest-density Poisson vertices removed."""
MIN_POINTS = 50
"""Fewer sparse points than this inside the object box is a failed run."""
MIN_REGISTERED = 3
"""SfM needs this many registered images to fix a similarity to the world frame."""
DENSE = "not available: pycolmap wheel has no CUDA (patch_match_stereo requires it); sparse points only"


class _Failed(Exception):
    """A run that produced no mesh; the message is the reason recorded in info.json."""


class _Stages:
    """One tqdm line over the stages of a run (silent when ``progress`` is False)."""

    def __init__(self, name: str, names: list[str], progress: bool):
        self.bar = tqdm(total=len(names), desc=name, disable=not progress, leave=False)
        self.seconds: dict[str, float] = {}
        self.current, self.t = None, time.perf_counter()

    def __call__(self, stage: str | None) -> None:
        now = time.perf_counter()
        if self.current is not None:
            self.seconds[self.current] = round(now - self.t, 3)
            self.bar.update(1)
        self.current, self.t = stage, now
        if stage is not None:
            self.bar.set_postfix_str(stage)

    def close(self) -> None:
        self(None)
        self.bar.close()


def _colmap_stage(fn, *args, **kwargs):
    """Run a pycolmap call; COLMAP's own errors become a failed run, not a traceback."""
    try:
        return fn(*args, **kwargs)
    except (RuntimeError, ValueError) as exc:
        msg = str(exc).strip().splitlines()
        raise _Failed(f"COLMAP error in {fn.__name__}: {msg[-1] if msg else type(exc).__name__}") from None


def _sparse_known(ws, views, seed: int, info: dict):
    rec = _colmap_stage(triangulate_known, ws, views, seed)
    centres = {iid: np.asarray(img.projection_center()) for iid, img in rec.images.items()}
    info["registered"] = f"{len(centres)} of {len(views)} images (known poses)"
    info["n_registered"] = len(centres)
    return points_and_observers(rec, centres)


def _sparse_sfm(ws, views, seed: int, info: dict):
    rec = _colmap_stage(incremental_sfm, ws, seed, MIN_REGISTERED)
    reg = [] if rec is None else [img for img in rec.images.values() if img.has_pose]
    info["registered"] = f"{len(reg)} of {len(views)} images"
    info["n_registered"] = len(reg)
    if len(reg) < MIN_REGISTERED:
        raise _Failed(f"SfM registered {len(reg)} of {len(views)} images (needs {MIN_REGISTERED})")
    model_c = np.array([img.projection_center() for img in reg], np.float64)
    world_c = np.array([views.c2w[ws.index(img.name)][:3, 3] for img in reg])
    s, r, t, inl = robust_umeyama(model_c, world_c)
    res = np.linalg.norm(apply_similarity(model_c, s, r, t) - world_c, axis=1)
    radius = np.linalg.norm(world_c - world_c.mean(0), axis=1).mean()
    info["alignment"] = {"scale": s, "inliers": int(inl.sum()),
                         "rms_centre_error": float(np.sqrt((res[inl] ** 2).mean())),
                         "rms_relative_to_ring": float(np.sqrt((res[inl] ** 2).mean()) / max(radius, 1e-12))}
    centres = {img.image_id: np.asarray(img.projection_center()) for img in reg}
    pts, dirs, lengths = points_and_observers(rec, centres)
    return apply_similarity(pts, s, r, t), dirs @ r.T, lengths


def _run(name: str, known: bool, views_path, out, profile: str, seed: int, progress: bool,
         n_input_views: int | None) -> dict:
    if profile not in PROFILES:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(PROFILES)})")
    t0 = time.perf_counter()
    prof = PROFILES[profile]
    views = input_views(views_path, n_input_views)
    lo, hi = object_box(views)
    info = {"method": name, "views": len(views), "profile": profile, "seed": int(seed),
            "max_features": prof["max_features"], "sift_first_octave": prof["first_octave"],
            "poisson_depth": prof["poisson_depth"],
            "intrinsics": "known, fixed", "dense": DENSE}
    import pycolmap

    pycolmap.set_random_seed(int(seed))
    stages = _Stages(name, ["sift", "match", "triangulate" if known else "sfm", "poisson"], progress)
    workspace = None
    try:
        with tempfile.TemporaryDirectory(prefix="ipm_colmap_") as tmp, quiet_colmap(False):
            workspace = tmp
            ws = make_workspace(views, Path(tmp))  # UserError on missing rgb files
            stages("sift")
            _colmap_stage(extract, ws, views, prof["max_features"], prof["first_octave"])
            stages("match")
            _colmap_stage(match, ws, seed)
            stages("triangulate" if known else "sfm")
            pts, dirs, lengths = (_sparse_known if known else _sparse_sfm)(ws, views, seed, info)
        stages("poisson")
        inside = np.all((pts >= lo) & (pts <= hi), axis=1)
        info["points"], info["points_in_box"] = len(pts), int(inside.sum())
        if len(pts):
            info["mean_track_length"] = float(lengths.mean())
            info["two_view_share"] = float((lengths == 2).mean())
        if inside.sum() < MIN_POINTS:
            raise _Failed(f"{int(inside.sum())} sparse points in the object box (needs {MIN_POINTS})")
        pts, dirs = pts[inside], dirs[inside]
        normals = oriented_normals(pts, dirs)
        try:
            verts, faces = poisson_mesh(pts, normals, prof["poisson_depth"], TRIM, (lo, hi), seed)
        except MeshingError as exc:
            raise _Failed(f"Poisson: {exc}") from None
    except _Failed as exc:
        stages.close()
        reason = str(exc) if workspace is None else str(exc).replace(workspace, "<COLMAP workspace>")
        return write_failure(out, t0, {**info, "stage_seconds": stages.seconds}, reason)
    except BaseException:
        stages.close()
        raise
    stages.close()
    info["stage_seconds"] = stages.seconds
    info["mesh_vertices"], info["mesh_faces"] = len(verts), len(faces)
    return write_result(out, verts, faces, t0, info)


def run_colmap_known(views_path, out, profile: str = "default", seed: int = 0, progress: bool = True,
                     n_input_views: int | None = None, **_) -> dict:
    """``ipm baseline colmap_known``: SIFT, exhaustive matching, triangulation at the known
    poses, Poisson. Writes OUT/mesh.ply (world frame), timing.json, info.json."""
    return _run("colmap_known", True, views_path, out, profile, seed, progress, n_input_views)


def run_colmap_sfm(views_path, out, profile: str = "default", seed: int = 0, progress: bool = True,
                   n_input_views: int | None = None, **_) -> dict:
    """``ipm baseline colmap_sfm``: SIFT, exhaustive matching, incremental SfM, similarity to
    the known camera centres, Poisson. Writes OUT/mesh.ply (world frame), timing.json, info.json."""
    return _run("colmap_sfm", False, views_path, out, profile, seed, progress, n_input_views)
