"""Impostors: the reference and the candidate seen through the same small square window.

Each input view's reference is cut to a square window around the object's pixel bounding box
(``margin`` on every side) and resampled to ``impostor`` pixels (area coverage per part, then the
majority rule: ``ipm.render.semantic.resample_labels``); a candidate is ray cast (open3d, closest
hit) through the same window at the same size, so both images are aligned pixel for pixel and the
object fills most of the impostor whatever the photo's size (the authors' impostors are 256 px;
``default`` uses 128 px, see ``ipm.methods.ga_options.PROFILE_OPTIONS``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ipm.errors import UserError
from ipm.pose import yaw_matrix

if TYPE_CHECKING:
    from ipm.generators.base import Mesh
    from ipm.methods.ga_options import GAOptions


@dataclass
class Target:
    """One reference impostor: camera, window in the view's pixels and the reduced labels."""

    c2w: np.ndarray
    """Camera-to-world matrix (4, 4) of the view, OpenGL convention."""
    fov_x: float
    """Horizontal field of view of the view (radians)."""
    width: int
    """Width of the view in pixels."""
    height: int
    """Height of the view in pixels."""
    window: tuple[float, float, float, float]
    """The impostor's region of the view: (x0, y0, x1, y1) in pixels."""
    labels: np.ndarray
    """(impostor, impostor) uint8 reference labels (0 background, 1 + part)."""
    stats: object = None
    """``TreeStats`` of ``labels`` (tree loss), built once."""
    mirror: np.ndarray | None = None
    """The reference's silhouette mirrored about its root (the outline seen from behind)."""
    rays: np.ndarray = field(default=None, repr=False)
    """The impostor's rays (impostor, impostor, supersample**2, 6), cast for every candidate."""


def make_target(labels: np.ndarray, c2w: np.ndarray, fov_x: float, options: GAOptions) -> Target:
    """Cut the reference label image (H, W) to a square window around the object (``margin`` on
    each side) and resample it to ``options.impostor`` pixels (area coverage, majority rule)."""
    from ipm.render.semantic import pixel_rays, resample_labels

    labels = np.asarray(labels, np.uint8)
    h, w = labels.shape
    box = bbox(labels)
    if box is None:
        raise UserError("the reference view has no object pixels")
    top, bottom, left, right = box
    side = max(bottom - top, right - left) * (1.0 + 2.0 * options.margin)
    cx, cy = 0.5 * (left + right), 0.5 * (top + bottom)
    window = (cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2)
    size = (options.impostor, options.impostor)
    reduced = resample_labels(labels, window, size, n_parts=max(2, int(labels.max())))
    if not reduced.any():
        raise UserError("the reference object vanishes at the impostor resolution")
    rays = pixel_rays(c2w, fov_x, w, h, window, size, options.supersample)[0]
    return Target(np.asarray(c2w), fov_x, w, h, window, reduced, rays=rays)


def bbox(labels: np.ndarray):
    """Pixel box (top, bottom, left, right) of the non-zero labels, ends exclusive; None if empty."""
    rows, cols = np.flatnonzero(labels.any(1)), np.flatnonzero(labels.any(0))
    if rows.size == 0:
        return None
    return rows[0], rows[-1] + 1, cols[0], cols[-1] + 1


def turned_rays(rays: np.ndarray, base: np.ndarray, turns: int) -> np.ndarray:
    """``rays`` (..., 6) turned about the vertical through ``base`` by ``2 pi k / turns``, k =
    0..turns-1, on a new axis after the first (turning the rays by -a shows the object turned by a)."""
    return TurnedRays(rays, turns)(base)


class TurnedRays:
    """:func:`turned_rays` of fixed ``rays`` (targets, ..., 6) for many ``base`` points: the turned
    directions do not depend on the base and are made once; the origins are turned once per
    target, as every ray of a target's window starts at its camera (the rays of ``pixel_rays``)."""

    def __init__(self, rays: np.ndarray, turns: int):
        rays = np.asarray(rays)
        self.shape = (rays.shape[0], turns) + rays.shape[1:]
        self.rots = [yaw_matrix(-2.0 * math.pi * k / turns) for k in range(turns)]
        d = rays[..., 3:].astype(np.float64)
        self.dirs = np.stack([(d @ rot.T).astype(np.float32) for rot in self.rots], axis=1)
        flat = rays[..., :3].reshape(rays.shape[0], -1, 3)
        shared = bool(np.all(flat == flat[:, :1]))
        # one origin per target where they all share it, shaped to broadcast over its rays
        self.origins = (flat[:, :1].reshape((rays.shape[0],) + (1,) * (rays.ndim - 2) + (3,)) if shared
                        else rays[..., :3]).astype(np.float64)

    def __call__(self, base: np.ndarray) -> np.ndarray:
        """The turned rays (targets, turns, ..., 6) about the vertical through ``base`` (3,)."""
        out = np.empty(self.shape, np.float32)
        out[..., 3:] = self.dirs
        o = self.origins - base
        for k, rot in enumerate(self.rots):
            out[:, k, ..., :3] = (o @ rot.T + base).astype(np.float32)
        return out


def cast_labels(vertices: np.ndarray, mesh: Mesh, rays: np.ndarray, base: np.ndarray, turns: int) -> np.ndarray:
    """Labels of ``mesh`` at world ``vertices`` through ``rays`` (targets, H, W, samples, 6) turned
    ``turns`` times about the vertical through ``base`` (:func:`turned_rays`): (targets, turns, H, W)."""
    from ipm.render.semantic import LabelCaster

    caster = LabelCaster(vertices, mesh.faces, mesh.labels, n_parts=max(2, len(mesh.part_names)))
    return caster.labels(turned_rays(rays, base, turns))


def cast_turned(vertices: np.ndarray, mesh: Mesh, rays: TurnedRays, base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cast_labels` as the loss uses it: the labels of the unturned view (targets, H, W)
    and only the silhouettes of the turned ones (targets, turns - 1, H, W), equal to their labels
    ``> 0`` and found by any-hit tests, which stop at the first triangle a ray meets."""
    from ipm.render.semantic import LabelCaster

    caster = LabelCaster(vertices, mesh.faces, mesh.labels, n_parts=max(2, len(mesh.part_names)))
    turned = rays(base)
    return caster.labels(turned[:, 0]), caster.silhouettes(turned[:, 1:])


def mirror_about(mask: np.ndarray, x: float) -> np.ndarray:
    """``mask`` (H, W) mirrored left to right about the vertical line at column position ``x``
    (pixel centres at i + 0.5); what leaves the image is dropped."""
    h, w = mask.shape
    src = np.rint(2.0 * x - 1.0 - np.arange(w)).astype(int)  # column i shows column 2x - 1 - i
    ok = (src >= 0) & (src < w)
    out = np.zeros_like(mask)
    out[:, ok] = mask[:, src[ok]]
    return out
