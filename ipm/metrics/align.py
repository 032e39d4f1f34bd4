"""Shape IoU: the silhouette IoU after the best yaw + translation + uniform-scale alignment.

A single-view reconstruction can get the shape right and its placement wrong (distance along
the camera ray traded against size). The world-frame IoU of :mod:`ipm.metrics.silhouette`
mixes both errors; :func:`shape_iou` removes the placement part by aligning the
reconstruction to the reference first, and reports the alignment it needed.

The alignment moves the reconstruction by ``x -> s R_y(yaw) (x - c) + c + t`` (``R_y``:
``ipm.pose.yaw_matrix``) with the pivot ``c`` the reconstruction's *base centre* (bounding-box
centre in x and z, lowest y; the world is y-up and objects stand on the ground), so ``t`` is the
displacement of the base centre and the yaw and the scale leave the base where it was. Instead of moving the mesh, every
candidate moves the camera rays by the inverse transform, so the ray casting scene of the
(possibly 600k-triangle) reconstruction is built once.
"""
from __future__ import annotations

import math

import numpy as np
import trimesh
from scipy.optimize import minimize

from ipm.pose import yaw_matrix
from ipm.runtime import thread_count

from .silhouette import (FOV_DEG, bounding_sphere, camera_rays, check_reference, fibonacci_cameras, finite_part,
                         open3d, raycast_masks, raycasting_scene, view_ious)

SCALE_RANGE = 2.0  # the scale is searched within [min(1, s0) / 2, 2 max(1, s0)], s0 the bounding-box match
SHIFT_LIMIT = 2.0  # |t| is kept within 2 reference radii (the cameras see about 2.9 r across) of the origin, or
# of the box match where that lies further (a result placed far off the reference, as a photo's wrong camera puts it)


def similarity_matrix(yaw: float, translation, scale: float, pivot) -> np.ndarray:
    """4x4 matrix of ``x -> scale * R_y(yaw) (x - pivot) + pivot + translation``."""
    m = np.eye(4)
    m[:3, :3] = scale * yaw_matrix(yaw)
    m[:3, 3] = np.asarray(pivot, float) + np.asarray(translation, float) - m[:3, :3] @ np.asarray(pivot, float)
    return m


def base_centre(mesh: trimesh.Trimesh) -> np.ndarray:
    """Bounding-box centre in x and z at the lowest y: the pivot of the alignment."""
    lo, hi = mesh.bounds
    return np.array([(lo[0] + hi[0]) / 2.0, lo[1], (lo[2] + hi[2]) / 2.0])


class _MovedMeshMasks:
    """Masks of one reconstruction under any similarity transform, from one ray casting scene.

    Seeing the moved mesh ``s R (x - c) + c + t`` along the ray ``o + u d`` is seeing the mesh
    along ``R^T (o - c - t) / s + c + u R^T d / s``. Occlusion tests are any-hit with
    ``tfar = inf``, so the direction's length does not matter and the ``1 / s`` is dropped.
    """

    def __init__(self, mesh: trimesh.Trimesh, cams, res: int, pivot: np.ndarray, fov_deg: float = FOV_DEG):
        self.scene = raycasting_scene(mesh)
        self.origins, self.dirs = camera_rays(cams, res, fov_deg)
        self.pivot = pivot
        self.shape = (len(self.origins), res, res)
        self.rays = np.empty(self.dirs.shape[:2] + (6,), dtype=np.float32)

    def __call__(self, yaw: float, translation, scale: float) -> np.ndarray:
        """Boolean masks (n, res, res) of the mesh moved by the transform."""
        rot = yaw_matrix(yaw)
        if yaw == 0.0 and scale == 1.0 and not np.any(translation):
            self.rays[..., :3] = self.origins[:, None, :]
            self.rays[..., 3:] = self.dirs
        else:
            # R^T v for row vectors is v @ R
            origins = (self.origins - self.pivot - np.asarray(translation, float)) @ rot / scale + self.pivot
            self.rays[..., :3] = origins[:, None, :]
            np.matmul(self.dirs, rot.astype(np.float32), out=self.rays[..., 3:])
        hit = self.scene.test_occlusions(open3d().core.Tensor(self.rays), nthreads=thread_count()).numpy()
        return hit.reshape(self.shape)


def _box_match(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, pivot: np.ndarray) -> tuple[float, np.ndarray]:
    """Scale and translation that match the mesh's height and base centre to the reference's.

    Falls back to the bounding-sphere radius ratio when either height is degenerate (flat
    objects), and to scale 1 for a mesh of zero extent.
    """
    ref_h = np.ptp(reference.vertices[:, 1])
    rec_h = np.ptp(mesh.vertices[:, 1])
    ref_r, rec_r = bounding_sphere(reference)[1], bounding_sphere(mesh)[1]
    if rec_h > 1e-3 * rec_r and ref_h > 1e-3 * ref_r:
        scale = ref_h / rec_h
    else:
        scale = ref_r / rec_r if rec_r > 0 else 1.0
    return float(np.clip(scale, 0.1, 10.0)), base_centre(reference) - pivot


def align_similarity(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, n_views: int = 24, res: int = 64,
                     seed: int = 0, n_yaws: int = 24, n_starts: int = 3, max_evals: int = 100,
                     fov_deg: float = FOV_DEG) -> dict:
    """Yaw, translation and uniform scale of the mesh that maximise the mean silhouette IoU.

    Search views are ``n_views`` Fibonacci cameras at ``res`` px framed on the reference's
    bounding sphere, like the metric's. Scheme: two placements (as is, and height + base
    centre matched to the reference) times ``n_yaws`` yaws; the ``n_starts`` best distinct
    yaws are refined in all five parameters by Nelder-Mead (``max_evals // 2`` evaluations
    each) and the best of them is polished with a 4x smaller simplex (``max_evals``). The
    identity is always a candidate, so the search IoU is never below the unaligned one.

    Parameters
    ----------
    reference, mesh : trimesh.Trimesh
        Reference (valid, see ``check_reference``) and reconstruction (non-finite faces dropped).
    seed : int
        Accepted for a stable signature; the search is deterministic and draws no random numbers.

    Returns
    -------
    dict
        ``yaw`` (radians), ``translation`` (3,), ``scale``, ``pivot`` (3,), ``matrix`` (4x4) of
        ``x -> scale R_y(yaw) (x - pivot) + pivot + translation``, ``search_iou`` (mean IoU on
        the search views after alignment), ``identity_iou`` (before) and ``n_evals``.
    """
    del seed  # deterministic search
    check_reference(reference)
    mesh = finite_part(mesh)
    if len(mesh.faces) == 0:
        return _result(0.0, np.zeros(3), 1.0, np.zeros(3), 0.0, 0.0, 0)
    centre, radius = bounding_sphere(reference)
    cams = fibonacci_cameras(centre, radius, n_views, fov_deg)
    ref = raycast_masks(reference, cams, res, fov_deg)
    pivot = base_centre(mesh)
    masks = _MovedMeshMasks(mesh, cams, res, pivot, fov_deg)
    s0, t0 = _box_match(reference, mesh, pivot)
    log_lo, log_hi = math.log(min(1.0, s0) / SCALE_RANGE), math.log(max(1.0, s0) * SCALE_RANGE)
    centre_t = t0 / radius if np.linalg.norm(t0) > SHIFT_LIMIT * radius else np.zeros(3)
    cache: dict[tuple, float] = {}

    def clip(p):
        p = np.asarray(p, float).copy()
        p[0] = (p[0] + math.pi) % (2.0 * math.pi) - math.pi
        shift = np.linalg.norm(p[1:4] - centre_t)
        if shift > SHIFT_LIMIT:
            p[1:4] = centre_t + (p[1:4] - centre_t) * (SHIFT_LIMIT / shift)
        p[4] = min(max(p[4], log_lo), log_hi)
        return p

    def score(p):
        """Mean search IoU of parameters ``[yaw, t / r (3), log scale]``."""
        p = clip(p)
        key = tuple(np.round(p, 12))
        if key not in cache:
            cache[key] = float(view_ious(ref, masks(p[0], p[1:4] * radius, math.exp(p[4]))).mean())
        return cache[key]

    identity = np.zeros(5)
    identity_iou = score(identity)
    placements = [np.zeros(4), np.append(t0 / radius, math.log(s0))]
    grid = []
    for yaw in np.arange(n_yaws) * (2.0 * math.pi / n_yaws):
        for place in placements:
            p = np.concatenate([[yaw], place])
            grid.append((score(p), p))
    grid.sort(key=lambda sp: -sp[0])
    starts, seen_yaws = [], []
    for _, p in grid:  # best first, one start per yaw
        if p[0] not in seen_yaws:
            starts.append(p)
            seen_yaws.append(p[0])
        if len(starts) == n_starts:
            break

    def refine(p, steps, evals):
        simplex = np.vstack([p, p + np.diag(steps)])
        res_ = minimize(lambda q: -score(q), p, method="Nelder-Mead",
                        options={"initial_simplex": simplex, "maxfev": evals, "xatol": 1e-3, "fatol": 1e-4})
        return clip(res_.x)

    yaw_step = math.pi / n_yaws  # half a grid cell
    coarse = np.array([yaw_step, 0.05, 0.05, 0.05, 0.08])
    results = [refine(p, coarse, max_evals // 2) for p in starts]
    best = max(results, key=score)
    best = refine(best, coarse / 4.0, max_evals)
    candidates = [identity] + [p for _, p in grid[:1]] + results + [best]
    best = max(candidates, key=score)  # identity first: ties keep the unaligned mesh
    return _result(best[0], best[1:4] * radius, math.exp(best[4]), pivot, score(best), identity_iou, len(cache))


def _result(yaw, translation, scale, pivot, search_iou, identity_iou, n_evals) -> dict:
    return {
        "yaw": float(yaw),
        "translation": np.asarray(translation, float),
        "scale": float(scale),
        "pivot": np.asarray(pivot, float),
        "matrix": similarity_matrix(yaw, translation, scale, pivot),
        "search_iou": float(search_iou),
        "identity_iou": float(identity_iou),
        "n_evals": int(n_evals),
    }


def shape_iou(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, n_views: int = 64, res: int = 256,
              fov_deg: float = FOV_DEG, search_views: int = 24, search_res: int = 64, masks: tuple | None = None,
              **search) -> dict:
    """The metric's 64-view silhouette IoU after :func:`align_similarity`, with the alignment used.

    The aligned and the unaligned mesh are both seen from the metric's cameras at full
    resolution through one ray casting scene; if alignment does not raise the full-resolution
    IoU (it was chosen on coarser views), the unaligned result with the identity is returned,
    so ``shape_iou >= world_iou`` always. ``world_iou`` equals ``silhouette_iou``'s ``iou_mean``.
    ``search_views`` and ``search_res`` are :func:`align_similarity`'s ``n_views`` and ``res``,
    never more than the metric's own (a 16-view, 64 px smoke evaluation searches on those); its
    other options pass through ``search``. ``masks``: :func:`silhouette_masks`'s result for
    the metric's arguments, if already cast (the reference's and the unaligned mesh's are reused).

    Returns
    -------
    dict
        ``shape_iou``, ``shape_iou_min``, ``world_iou``, ``align_yaw_deg``, ``align_shift``
        (|t| / reference bounding-sphere radius), ``align_scale``, ``align_translation``,
        ``align_pivot`` and ``align_search_iou``, all JSON-serialisable.
    """
    check_reference(reference)
    fine = finite_part(mesh)
    centre, radius = bounding_sphere(reference)
    if len(fine.faces) == 0:
        return _shape_dict(0.0, 0.0, 0.0, _result(0.0, np.zeros(3), 1.0, np.zeros(3), 0.0, 0.0, 0), radius)
    align = align_similarity(reference, fine, min(search_views, n_views), min(search_res, res), fov_deg=fov_deg,
                             **search)
    if masks is None:
        cams = fibonacci_cameras(centre, radius, n_views, fov_deg)
        ref = raycast_masks(reference, cams, res, fov_deg)
        moved_masks = _MovedMeshMasks(fine, cams, res, align["pivot"], fov_deg)
        world = view_ious(ref, moved_masks(0.0, np.zeros(3), 1.0))
    else:
        ref, rec, cams = masks
        moved_masks = _MovedMeshMasks(fine, cams, res, align["pivot"], fov_deg)
        world = view_ious(ref, rec)
    moved = view_ious(ref, moved_masks(align["yaw"], align["translation"], align["scale"]))
    if moved.mean() < world.mean():
        align = _result(0.0, np.zeros(3), 1.0, align["pivot"], align["identity_iou"], align["identity_iou"],
                        align["n_evals"])
        moved = world
    return _shape_dict(float(moved.mean()), float(moved.min()), float(world.mean()), align, radius)


def _shape_dict(shape, shape_min, world, align, radius) -> dict:
    return {
        "shape_iou": shape,
        "shape_iou_min": shape_min,
        "world_iou": world,
        "align_yaw_deg": math.degrees(align["yaw"]),
        "align_shift": float(np.linalg.norm(align["translation"]) / radius),
        "align_scale": align["scale"],
        "align_translation": [float(x) for x in align["translation"]],
        "align_pivot": [float(x) for x in align["pivot"]],
        "align_search_iou": align["search_iou"],
    }
