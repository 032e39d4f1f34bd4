"""Silhouette IoU from a fixed ring of Fibonacci-sphere cameras, by ray casting.

Masks are computed with open3d's Embree-backed ``RaycastingScene`` so the metric is
independent of the (differentiable) Mitsuba renderer used for optimisation.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ipm.runtime import thread_count

if TYPE_CHECKING:
    import trimesh

FOV_DEG = 40.0
DISTANCE_MARGIN = 1.25  # camera distance = margin * r / sin(fov / 2): the sphere fills 80 % of the view


def bounding_sphere(mesh: trimesh.Trimesh) -> tuple[np.ndarray, float]:
    """Centre and radius of the sphere around the axis-aligned bounding box.

    The radius is half the box diagonal (not the minimal enclosing sphere): cheap,
    deterministic and the scale unit used to normalise every metric.
    """
    lo, hi = mesh.bounds
    return (lo + hi) / 2.0, float(np.linalg.norm(hi - lo) / 2.0)


def check_reference(mesh: trimesh.Trimesh) -> None:
    """Raise ValueError when the reference cannot define the cameras and scale."""
    if len(mesh.faces) == 0:
        raise ValueError("reference mesh is empty (0 faces)")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError("reference mesh has non-finite vertex coordinates")


def finite_part(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Drop faces touching non-finite vertices, so a diverged reconstruction scores low instead of crashing."""
    import trimesh

    ok = np.isfinite(mesh.vertices).all(axis=1)
    if ok.all():
        return mesh
    part = trimesh.Trimesh(mesh.vertices, mesh.faces[ok[mesh.faces].all(axis=1)], process=False)
    part.remove_unreferenced_vertices()
    return part


def open3d():
    """The open3d module, imported on first use: only the metrics need it, so the reconstruction
    paths also run where it is not installed (the GPU machine used by ``bench/``)."""
    import open3d

    return open3d


def raycasting_scene(mesh: trimesh.Trimesh) -> open3d.t.geometry.RaycastingScene:
    """Build an open3d ray casting scene holding the mesh triangles (an empty mesh gives an empty scene)."""
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene(nthreads=thread_count())
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32).reshape(-1, 3)),
        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32).reshape(-1, 3)),
    )
    return scene


def fibonacci_cameras(center: np.ndarray, radius: float, n_views: int = 64, fov_deg: float = FOV_DEG) -> list[np.ndarray]:
    """Camera-to-world matrices (OpenGL: looks down -z, +y up, +x right) on a Fibonacci sphere.

    Every camera looks at ``center`` from distance 1.25 r / sin(fov / 2), so the
    bounding sphere always fits in the view. World is y-up; the up vector falls back
    to z for views nearly parallel to y.
    """
    center = np.asarray(center, dtype=float)
    distance = DISTANCE_MARGIN * radius / np.sin(np.radians(fov_deg) / 2.0)
    i = np.arange(n_views) + 0.5
    y = 1.0 - 2.0 * i / n_views
    ring = np.sqrt(1.0 - y**2)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    dirs = np.stack([ring * np.cos(phi), y, ring * np.sin(phi)], axis=1)
    cams = []
    for d in dirs:
        back = d  # camera +z points away from the centre
        up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.99 else np.array([0.0, 0.0, 1.0])
        right = np.cross(up, back)
        right /= np.linalg.norm(right)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2] = right, np.cross(back, right), back
        c2w[:3, 3] = center + distance * d
        cams.append(c2w)
    return cams


def camera_rays(cams: list, res: int = 256, fov_deg: float = FOV_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Camera origins (n, 3) and float32 pixel-centre directions (n, res * res, 3), row 0 at the top."""
    t = np.tan(np.radians(fov_deg) / 2.0)
    s = ((np.arange(res) + 0.5) / res * 2.0 - 1.0) * t
    u, v = np.meshgrid(s, -s)  # columns go right (+x), rows go down (-y)
    pix = np.stack([u, v, -np.ones_like(u)], axis=-1).reshape(-1, 3)
    c2w = np.asarray(cams, dtype=float)
    return c2w[:, :3, 3].copy(), np.matmul(pix, c2w[:, :3, :3].transpose(0, 2, 1)).astype(np.float32)


def raycast_masks(mesh: trimesh.Trimesh, cams: list, res: int = 256, fov_deg: float = FOV_DEG) -> np.ndarray:
    """Binary masks (n, res, res), row 0 at the top: a pixel is set if its centre ray hits any triangle.

    All views go through one batched ``test_occlusions`` call (any-hit, cheaper than closest-hit).
    """
    origins, dirs = camera_rays(cams, res, fov_deg)
    rays = np.empty(dirs.shape[:2] + (6,), dtype=np.float32)
    rays[..., :3] = origins[:, None, :]
    rays[..., 3:] = dirs
    hit = raycasting_scene(mesh).test_occlusions(open3d().core.Tensor(rays), nthreads=thread_count()).numpy()
    return hit.reshape(len(origins), res, res)


def silhouette_masks(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, n_views: int = 64, res: int = 256,
                     fov_deg: float = FOV_DEG, reference_masks: np.ndarray | None = None,
                     ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Masks of reference and reconstruction from the same cameras, framed on the reference;
    ``reference_masks``: the reference's, if already cast for these arguments (:func:`read_reference_masks`)."""
    check_reference(reference)
    center, radius = bounding_sphere(reference)
    cams = fibonacci_cameras(center, radius, n_views, fov_deg)
    ref = raycast_masks(reference, cams, res, fov_deg) if reference_masks is None else reference_masks
    return ref, raycast_masks(finite_part(mesh), cams, res, fov_deg), cams


def _sha256(path) -> str:
    """SHA-256 of the file at ``path`` (what identifies a reference the masks were cast from)."""
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def write_reference_masks(reference_path, out_path, n_views: int = 64, res: int = 256,
                          fov_deg: float = FOV_DEG) -> None:
    """The reference's masks from the metric's cameras, cast once per case for every evaluation of
    it (an npz: the masks bit-packed, the arguments and the reference file's SHA-256), atomically."""
    from ipm.io import load_mesh
    from ipm.io.atomic import atomic_path

    reference = load_mesh(reference_path)
    check_reference(reference)
    cams = fibonacci_cameras(*bounding_sphere(reference), n_views, fov_deg)
    masks = raycast_masks(reference, cams, res, fov_deg)
    sha = _sha256(reference_path)
    with atomic_path(out_path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, masks=np.packbits(masks, axis=-1), shape=np.array(masks.shape), fov_deg=fov_deg,
                            reference_sha256=sha)


def read_reference_masks(path, reference_path, n_views: int, res: int, fov_deg: float = FOV_DEG) -> np.ndarray:
    """The masks :func:`write_reference_masks` wrote for the file ``reference_path``; a file made
    for other arguments or another reference is refused with one line (``UserError``)."""
    from ipm.errors import UserError

    try:
        with np.load(path) as data:
            shape, packed = tuple(int(k) for k in data["shape"]), data["masks"]
            fov, sha = float(data["fov_deg"]), str(data["reference_sha256"])
    except (OSError, KeyError, ValueError) as exc:
        raise UserError(f"reference masks {path}: not a reference-masks file ({exc})") from None
    if shape != (n_views, res, res) or fov != fov_deg:
        raise UserError(f"reference masks {path}: cast for {shape[0]} views at {shape[-1]} px, "
                        f"{fov:g} degrees, not {n_views} views at {res} px, {fov_deg:g} degrees")
    if sha != _sha256(reference_path):
        raise UserError(f"reference masks {path}: cast from another file than {reference_path}")
    return np.unpackbits(packed, axis=-1, count=res).astype(bool).reshape(shape)


def view_ious(ref: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """Per-view mask IoU of two mask stacks (n, H, W); 1 where both masks are empty."""
    inter = (ref & rec).sum(axis=(1, 2))
    union = (ref | rec).sum(axis=(1, 2))
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def silhouette_iou(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, n_views: int = 64, res: int = 256,
                   fov_deg: float = FOV_DEG, masks: tuple | None = None) -> dict:
    """Per-view mask IoU (1 when both masks are empty) and its mean, min, std and above/below-horizon means.

    A view is above the horizon if its camera is higher (y) than the reference centre;
    a group without views (only possible for tiny n_views) gets NaN. ``masks``: the result of
    :func:`silhouette_masks` for these arguments, if already cast.
    """
    ref, rec, cams = masks if masks is not None else silhouette_masks(reference, mesh, n_views, res, fov_deg)
    iou = view_ious(ref, rec)
    height = np.array([c[1, 3] for c in cams]) - bounding_sphere(reference)[0][1]

    def mean(sel):
        return float(iou[sel].mean()) if sel.any() else float("nan")

    return {
        "iou_mean": float(iou.mean()),
        "iou_min": float(iou.min()),
        "iou_std": float(iou.std()),
        "iou_above": mean(height > 0),
        "iou_below": mean(height < 0),
        "per_view": [float(x) for x in iou],
    }
