"""Masks from the image, for an object photographed on a plain background (no model weights).

A colour model of the background is fitted to the image's border (mean and covariance in CIELAB,
refitted without the border pixels that look least like it, where the object touches the edge);
a pixel is object where its Mahalanobis distance to that model exceeds :data:`MARGIN` times the
distance that all but 0.5 % of the border stays under. Specks are removed, small holes
filled (large ones stay: the sky between a tree's branches) and only components of at least 5 % of
the largest are kept.
"""
from __future__ import annotations

import numpy as np

from ipm.errors import UserError

MARGIN = 2.0
"""A pixel is object where its distance to the background model is this many times the distance
all but 0.5 % of the border stays under (at least 1: one CIELAB unit on a flat background)."""


def _border(image: np.ndarray, width: int) -> np.ndarray:
    """The pixels (k, channels) of a frame ``width`` pixels wide around the image."""
    top, bottom = image[:width].reshape(-1, image.shape[-1]), image[-width:].reshape(-1, image.shape[-1])
    left, right = image[width:-width, :width], image[width:-width, -width:]
    return np.concatenate([top, bottom, left.reshape(-1, image.shape[-1]), right.reshape(-1, image.shape[-1])])


def _distance(pixels: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Mahalanobis distance of ``pixels`` (..., 3) to the Gaussian of ``sample`` (k, 3)."""
    mean = sample.mean(0)
    cov = np.cov(sample.T) + np.eye(3) * 1.0  # 1 Lab unit of floor: a flat render's border has none
    d = pixels - mean
    return np.sqrt(np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d))


def mask_from_image(rgb: np.ndarray) -> np.ndarray:
    """Object mask (H, W) float32 in {0, 1} of an RGB image (H, W, 3; uint8, or float in [0, 1])
    whose border shows the background; ``UserError`` when nothing stands out from it."""
    from skimage.color import rgb2lab
    from skimage.measure import label
    from skimage.morphology import disk, opening, remove_small_holes, remove_small_objects

    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] < 3 or min(rgb.shape[:2]) < 16:
        raise UserError(f"cannot segment an image of shape {rgb.shape}: needs an RGB image of at least 16 x 16")
    img = rgb[..., :3].astype(np.float64) / (255.0 if rgb.dtype == np.uint8 else 1.0)
    lab = rgb2lab(np.clip(img, 0.0, 1.0))
    h, w = lab.shape[:2]
    border = _border(lab, max(2, int(round(0.02 * min(h, w)))))
    d_border = _distance(border, border)
    border = border[d_border <= np.quantile(d_border, 0.9)]  # the object where it touches the edge
    dist = _distance(lab, border)
    floor = np.quantile(_distance(border, border), 0.995)
    if dist.max() <= MARGIN * max(floor, 1.0):
        raise UserError("no object stands out from the colours at the image's border: give a mask")
    mask = opening(dist > MARGIN * max(floor, 1.0), disk(1))
    area = h * w
    mask = remove_small_objects(mask, max_size=max(4, int(1e-4 * area)))
    mask = remove_small_holes(mask, max_size=max(4, int(1e-3 * area)))
    labels = label(mask)
    if labels.max() == 0:
        raise UserError("no object stands out from the colours at the image's border: give a mask")
    sizes = np.bincount(labels.ravel())[1:]
    keep = np.nonzero(sizes >= 0.05 * sizes.max())[0] + 1
    return np.isin(labels, keep).astype(np.float32)
