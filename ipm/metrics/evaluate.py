"""All benchmark numbers for one reconstruction against its reference, plus a preview strip."""

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial import cKDTree

from ipm.io.atomic import atomic_path

from .align import shape_iou
from .recovery import camera_recovery, parameter_recovery
from .silhouette import (bounding_sphere, check_reference, fibonacci_cameras, finite_part, raycast_masks,
                         read_reference_masks, silhouette_iou, silhouette_masks)
from .volume import volumetric_iou

MIN_ANGLE_DEG = 5.0  # a triangle with a smaller interior angle is a sliver
MIN_AREA_REL = 1e-10  # ... and one with area below this times r^2 is degenerate


def chamfer(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, n_samples: int = 20000, seed: int = 0) -> dict:
    """Chamfer-L2 (mean squared NN distance both ways, summed, / r^2) and mean NN distance (both ways averaged, / r).

    Points are sampled uniformly by area with a fixed seed, so the numbers are reproducible
    and a mesh against itself scores exactly 0. An empty reconstruction gives inf.
    """
    check_reference(reference)
    mesh = finite_part(mesh)
    if len(mesh.faces) == 0:
        return {"chamfer_l2": float("inf"), "chamfer_l1": float("inf")}
    radius = bounding_sphere(reference)[1]
    a, _ = trimesh.sample.sample_surface(reference, n_samples, seed=seed)
    b, _ = trimesh.sample.sample_surface(mesh, n_samples, seed=seed)
    d_ab = cKDTree(b).query(a, workers=-1)[0]
    d_ba = cKDTree(a).query(b, workers=-1)[0]
    return {
        "chamfer_l2": float((np.mean(d_ab**2) + np.mean(d_ba**2)) / radius**2),
        "chamfer_l1": float((np.mean(d_ab) + np.mean(d_ba)) / 2.0 / radius),
    }


def triangle_quality(mesh: trimesh.Trimesh, radius: float) -> dict:
    """Triangle count and share of malformed triangles (area < 1e-10 r^2 or smallest angle < 5 degrees)."""
    n = len(mesh.faces)
    if n == 0:
        return {"n_triangles": 0, "malformed_share": 0.0}
    tri = mesh.triangles
    area = trimesh.triangles.area(tri)
    with np.errstate(invalid="ignore", divide="ignore"):
        min_angle = np.degrees(trimesh.triangles.angles(tri).min(axis=1))
    bad = (area < MIN_AREA_REL * radius**2) | ~(min_angle >= MIN_ANGLE_DEG)  # NaN angles count as bad
    return {"n_triangles": int(n), "malformed_share": float(bad.mean())}


def evaluate_meshes(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, n_views: int = 64, res: int = 256,
                    grid: int = 128, seed: int = 0, reference_masks: np.ndarray | None = None) -> dict:
    """Every metric as a flat JSON-serialisable dict (silhouette per-view IoUs under ``iou_per_view``;
    ``shape_iou``: the same IoU after the best similarity alignment, ``ipm.metrics.align``);
    ``reference_masks``: the reference's metric masks, if cast before (the workflow casts them once a case)."""
    masks = silhouette_masks(reference, mesh, n_views, res, reference_masks=reference_masks)  # once for both IoUs
    sil = silhouette_iou(reference, mesh, n_views, res, masks=masks)
    sil["iou_per_view"] = sil.pop("per_view")
    shape = shape_iou(reference, mesh, n_views, res, masks=masks)
    shape.pop("world_iou")  # the same number as iou_mean
    return {
        **sil,
        **shape,
        **volumetric_iou(reference, mesh, grid),
        **chamfer(reference, mesh, seed=seed),
        **triangle_quality(mesh, bounding_sphere(reference)[1]),
    }


def preview_png(reference: trimesh.Trimesh, mesh: trimesh.Trimesh, path: str, n: int = 8, res: int = 128,
                n_views: int = 64) -> None:
    """Write a strip of ``n`` metric views: both masks white, reference only red, reconstruction only cyan.

    Views are spread evenly over the ``n_views`` metric cameras (only those are cast); the file is
    written atomically.
    """
    check_reference(reference)
    cams = fibonacci_cameras(*bounding_sphere(reference), n_views)
    cams = [cams[i] for i in np.linspace(0, n_views - 1, min(n, n_views)).round().astype(int)]
    ref, rec = (raycast_masks(m, cams, res)[..., None] for m in (reference, finite_part(mesh)))
    img = np.where(ref & rec, [255, 255, 255], np.where(ref, [220, 40, 40], np.where(rec, [40, 200, 220], 0)))
    img = np.pad(img, ((0, 0), (2, 2), (2, 2), (0, 0)), constant_values=90)  # grey frame between views
    strip = np.concatenate(list(img), axis=1).astype(np.uint8)
    with atomic_path(path) as tmp:
        Image.fromarray(strip).save(tmp, format="PNG")


def evaluate_files(reference_path, mesh_path, out_path, n_views: int = 64, res: int = 256, grid: int = 128,
                   preview_path=None, seed: int = 0, truth: dict | None = None, params: dict | None = None,
                   views=None, reference_masks=None) -> dict:
    """``ipm evaluate``: metrics of a mesh file against a reference file, written as JSON; with the
    case's ground truth and the reconstruction's params.json, also parameter recovery (the counts
    scored are those the input ``views`` folder's semantic images show, if given); with a
    params.json of a withheld camera, the camera's errors. ``reference_masks``: the file
    ``write_reference_masks`` made of this reference for these views and resolution."""
    from ipm.errors import UserError
    from ipm.io import load_mesh, write_json

    reference = load_mesh(reference_path)
    mesh = load_mesh(mesh_path, allow_empty=True)
    if n_views < 2 or res < 8 or grid < 8:
        raise UserError("need --views >= 2, --res >= 8 and --grid >= 8")
    if reference_masks is not None:
        reference_masks = read_reference_masks(reference_masks, reference_path, n_views, res)
    try:
        metrics = evaluate_meshes(reference, mesh, n_views=n_views, res=res, grid=grid, seed=seed,
                                  reference_masks=reference_masks)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if truth is not None:
        heights = [float(np.ptp(m.vertices[:, 1])) if len(m.vertices) else 0.0 for m in (reference, finite_part(mesh))]
        if views is not None and params is not None:
            from ipm.io import load_views

            views = load_views(Path(views) / "transforms.json")
        metrics.update(parameter_recovery(truth, params, *heights, views=views))
    metrics.update(camera_recovery(params))
    write_json(out_path, metrics)
    if preview_path is not None:
        preview_png(reference, mesh, str(preview_path))
    return metrics


def failure_files(reason: str, out_path, preview_path=None) -> None:
    """Metrics of a run that produced no mesh: only the reason (the table shows "-"), and a
    preview strip that says so."""
    from PIL import ImageDraw

    from ipm.io import write_json

    write_json(out_path, {"failed": reason})
    if preview_path is not None:
        img = Image.new("RGB", (8 * 132, 132), (40, 40, 40))
        ImageDraw.Draw(img).text((10, 58), f"no mesh: {reason}"[:150], fill=(230, 230, 230))
        with atomic_path(preview_path) as tmp:
            img.save(tmp, format="PNG")
