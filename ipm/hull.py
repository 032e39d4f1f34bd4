"""Where the masks of calibrated views agree: the object's working volume (the baselines carve
it) and its lowest point (the ground of a capture in another frame, ``ipm.capture``)."""
from __future__ import annotations

import numpy as np

from ipm.errors import UserError
from ipm.io.views import Views
from ipm.render.cameras import project


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
