"""Semantic label images (``docs/design``, "Semantic label images"): trees 0 = background,
1 = branch, 2 = foliage; buildings 0 = background, 1 = wall, 2 = window, 3 = roof, 4 = door
(``BUILDING_LABELS``).

The tree similarity loss (``ipm.losses.tree``) compares such images. A reference photo becomes
one by colour alone, as the paper does "in simple cases" ("green corresponds to leaves, brown or
gray - to branches and trunk"): :func:`labels_from_rgb`. Label images are stored as 8-bit
single-channel PNGs (the ``semantic_path`` files of ``transforms.json``).

Colour rules of :func:`labels_from_rgb` (channels in [0, 1], HSV hue in degrees):

- background: the mask where one is given (non-zero = object); otherwise the pixels within
  ``BG_TOLERANCE`` (0.12, largest channel difference) of the background colour, the median of
  the image border; on a white backdrop that is "near-white", on any plain backdrop
  "near-uniform";
- foliage: object pixels with hue in ``GREEN_HUE`` ([55, 175] degrees: yellow-green to
  blue-green), saturation >= ``MIN_SATURATION`` (0.12) and value >= ``MIN_VALUE`` (0.06): below
  that saturation or value the hue is noise (greys, deep shadow);
- branch: every other object pixel (brown hues 0-50 degrees, greys, near-black).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image

from ipm.errors import UserError
from ipm.io.atomic import atomic_path

BACKGROUND, BRANCH, FOLIAGE = 0, 1, 2
"""Label values, as ``semantic_labels`` in ``transforms.json``."""

LABEL_NAMES = {"background": BACKGROUND, "branch": BRANCH, "foliage": FOLIAGE}
"""Label name -> value of trees, the ``semantic_labels`` record."""

BUILDING_LABELS = {"background": 0, "wall": 1, "window": 2, "roof": 3, "door": 4}
"""Label name -> value of buildings: window masks are the pixels labelled ``window``."""

GREEN_HUE = (55.0, 175.0)
"""Hue band (degrees, inclusive) of foliage."""

MIN_SATURATION = 0.12
"""Least HSV saturation for a pixel to count as coloured (foliage needs it)."""

MIN_VALUE = 0.06
"""Least HSV value for a pixel's hue to be trusted (darker pixels are branches)."""

BG_TOLERANCE = 0.12
"""Largest per-channel difference from the border colour that still counts as background."""


def check_labels(labels, what: str = "label image", max_label: int = FOLIAGE) -> np.ndarray:
    """``labels`` as a uint8 (H, W) array with values in 0..``max_label`` (trees: 0 background,
    1 branch, 2 foliage); ``UserError`` otherwise."""
    if not isinstance(labels, np.ndarray):
        raise UserError(f"{what}: expected a numpy uint8 array, got {type(labels).__name__}")
    if labels.dtype != np.uint8:
        raise UserError(f"{what}: expected dtype uint8 label values, got {labels.dtype}")
    if labels.ndim != 2 or labels.shape[0] == 0 or labels.shape[1] == 0:
        raise UserError(f"{what}: expected a non-empty (H, W) array, got shape {labels.shape}")
    top = int(labels.max())
    if top > max_label:
        raise UserError(f"{what}: value {top} is not a label (0..{max_label})")
    return labels


def _as_unit_rgb(rgb) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1] from uint8 or float RGB(A); ``UserError`` otherwise."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] not in (3, 4) or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise UserError(f"RGB image: expected shape (H, W, 3) or (H, W, 4), got {rgb.shape}")
    rgb = rgb[..., :3]
    if rgb.dtype == np.uint8:
        return rgb.astype(np.float32) / 255.0
    if np.issubdtype(rgb.dtype, np.floating):
        if not np.isfinite(rgb).all() or rgb.min() < 0.0 or rgb.max() > 1.0:
            raise UserError("RGB image: float values must be finite and in [0, 1]")
        return rgb.astype(np.float32)
    raise UserError(f"RGB image: expected uint8 or float values, got {rgb.dtype}")


def _hsv(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hue (degrees, [0, 360)), saturation and value of a (H, W, 3) image in [0, 1]."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    mx = rgb.max(axis=-1)
    delta = mx - rgb.min(axis=-1)
    safe = np.where(delta > 0, delta, 1.0)
    hue = np.where(mx == r, ((g - b) / safe) % 6.0,
                   np.where(mx == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0)) * 60.0
    hue = np.where(delta > 0, hue, 0.0)
    sat = np.where(mx > 0, delta / np.where(mx > 0, mx, 1.0), 0.0)
    return hue, sat, mx


def labels_from_rgb(rgb, mask=None) -> np.ndarray:
    """Semantic labels of a tree photo by colour (rules and thresholds: module docstring).

    Parameters
    ----------
    rgb
        (H, W, 3) or (H, W, 4) image, uint8 or float in [0, 1]; alpha is ignored.
    mask
        Optional (H, W) object mask: non-zero (or > 0.5 for floats) = object. Without it the
        background is the colour of the image border.

    Returns
    -------
    (H, W) uint8 labels: 0 background, 1 branch, 2 foliage.
    """
    img = _as_unit_rgb(rgb)
    h, w = img.shape[:2]
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (h, w):
            raise UserError(f"mask of shape {mask.shape} does not match the {w}x{h} RGB image")
        obj = mask > 0.5 if np.issubdtype(mask.dtype, np.floating) else mask != 0
    else:
        border = np.concatenate([img[0], img[-1], img[:, 0], img[:, -1]])
        bg = np.median(border, axis=0)
        obj = np.abs(img - bg).max(axis=-1) > BG_TOLERANCE
    hue, sat, val = _hsv(img)
    green = (hue >= GREEN_HUE[0]) & (hue <= GREEN_HUE[1]) & (sat >= MIN_SATURATION) & (val >= MIN_VALUE)
    labels = np.zeros((h, w), np.uint8)
    labels[obj] = BRANCH
    labels[obj & green] = FOLIAGE
    return labels


def save_labels(path: str | os.PathLike, labels, max_label: int = FOLIAGE) -> None:
    """Write a label image as an 8-bit single-channel PNG, atomically."""
    labels = check_labels(labels, max_label=max_label)
    with atomic_path(path) as tmp:
        Image.fromarray(labels).save(tmp, format="PNG")


def load_labels(path: str | os.PathLike, w: int, h: int, max_label: int = FOLIAGE) -> np.ndarray:
    """Read an 8-bit label PNG of size ``w`` x ``h``; ``UserError`` for a missing, odd or bad file."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"label image not found: {path}")
    try:
        with Image.open(path) as im:
            if im.mode not in ("L", "P"):
                raise UserError(f"label image {path}: expected an 8-bit single-channel PNG, got mode {im.mode}")
            labels = np.asarray(im, dtype=np.uint8).copy()
    except UserError:
        raise
    except Exception as exc:
        raise UserError(f"cannot read label image {path}: {exc}") from None
    if labels.shape != (h, w):
        raise UserError(f"label image {path} is {labels.shape[1]}x{labels.shape[0]}, expected {w}x{h}")
    return check_labels(labels, f"label image {path}", max_label)
