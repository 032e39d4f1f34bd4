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
