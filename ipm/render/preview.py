"""Pictures of part-labelled meshes for the report: reference (top) and reconstruction (bottom)
with one colour per part, seen from the input camera and from two cameras around the object."""
from __future__ import annotations

import numpy as np

from ipm.io import load_mesh, load_views, part_labels
from ipm.io.views import save_rgb
from ipm.render.textured import render_parts


def _orbit(c2w: np.ndarray, centre: np.ndarray, degrees: float) -> np.ndarray:
    """``c2w`` turned by ``degrees`` about the vertical axis through ``centre``."""
    a = np.radians(degrees)
    rot = np.eye(4)
    rot[[0, 0, 2, 2], [0, 2, 0, 2]] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)
    to, back = np.eye(4), np.eye(4)
    to[:3, 3], back[:3, 3] = -centre, centre
    return back @ rot @ to @ c2w


def parts_sheet(reference: str, mesh: str, transforms: str, out_png: str, res: int = 192, spp: int = 32) -> None:
    """Write the comparison sheet ``out_png`` (2 rows x 3 views), atomically."""
    views = load_views(transforms, masks=False)
    ref = load_mesh(reference)
    rec = load_mesh(mesh, allow_empty=True)
    centre = ref.bounds.mean(0)
    cams = np.stack([_orbit(views.c2w[0], centre, d) for d in (0.0, 120.0, 240.0)])
    rows = []
    for m in (ref, rec):
        if len(m.faces) == 0:
            rows.append(np.zeros((3, res, res, 3)))
            continue
        rows.append(render_parts(m.vertices, m.faces, part_labels(m), cams, views.fov_x, res, res, spp))
    save_rgb(out_png, np.concatenate([np.concatenate(list(r), axis=1) for r in rows], axis=0))


def photo_sheet(photo: str, mesh: str, camera: dict, out_png: str, height: int = 256, spp: int = 32) -> None:
    """The figure of a photo's reconstruction (``ipm reconstruct --image``), atomically: the photo,
    the fitted parts over it as the estimated ``camera`` sees them, and the mesh turned by 120 and
    240 degrees about its vertical axis."""
    from PIL import Image

    from ipm.io.views import linear_from_srgb, open_image
    from ipm.metrics.silhouette import raycasting_scene

    img = open_image(photo, upright=True).convert("RGB")
    width = max(8, int(round(img.width * height / img.height)))
    rgb = np.asarray(img.resize((width, height), Image.BILINEAR), np.float64) / 255.0
    rgb = linear_from_srgb(rgb)
    m = load_mesh(mesh)
    c2w, fov = np.asarray(camera["transform_matrix"]), np.radians(camera["fov_x_deg"])
    centre = m.bounds.mean(0)
    cams = np.stack([_orbit(c2w, centre, d) for d in (0.0, 120.0, 240.0)])
    parts = render_parts(m.vertices, m.faces, part_labels(m), cams, fov, width, height, spp)
    f = 0.5 * width / np.tan(0.5 * fov)
    ys, xs = np.mgrid[0:height, 0:width] + 0.5
    d = np.stack([(xs - width / 2) / f, -(ys - height / 2) / f, -np.ones_like(xs)], -1).reshape(-1, 3) @ c2w[:3, :3].T
    rays = np.concatenate([np.broadcast_to(c2w[:3, 3], d.shape), d], 1).astype(np.float32)
    hit = np.isfinite(raycasting_scene(m).cast_rays(rays)["t_hit"].numpy()).reshape(height, width, 1)
    over = np.where(hit, 0.4 * rgb + 0.6 * parts[0], rgb)
    save_rgb(out_png, np.concatenate([rgb, over, parts[1], parts[2]], axis=1))
