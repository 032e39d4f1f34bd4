"""Masks made wrong by known amounts, as a person's or a segmentation tool's masks are: the edge
moved in or out, a ragged edge, a hole, a thin part missing. The workflow's mask rows (a methods
entry's ``mask``: :func:`degrade_views`) and the mask-robustness benchmark
(``bench/mask_robustness.py``) fit to each and report what the error costs.

Every function takes a boolean (H, W) mask and returns a new one of the same shape.
"""
from __future__ import annotations

import numpy as np


def _disk(radius: float) -> np.ndarray:
    """A boolean disk of ``radius`` pixels (centre pixel included), for morphology."""
    r = int(np.ceil(radius))
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return x * x + y * y <= radius * radius


def _signed_distance(mask: np.ndarray) -> np.ndarray:
    """Distance (pixels) from each pixel centre to the mask's edge, positive inside."""
    from scipy import ndimage

    return np.where(mask, ndimage.distance_transform_edt(mask), -ndimage.distance_transform_edt(~mask))


def shift_edge(mask: np.ndarray, pixels: float) -> np.ndarray:
    """The edge moved outwards by ``pixels`` (inwards where negative): the pixels whose centre lies
    within that distance outside the edge join the mask (or, inwards, leave it)."""
    mask = np.asarray(mask, bool)
    if pixels == 0:
        return mask.copy()
    d = _signed_distance(mask)
    return d > -abs(pixels) - 0.5 if pixels > 0 else d > abs(pixels) + 0.5


def ragged_edge(mask: np.ndarray, amplitude: float, rng: np.random.Generator, scale: float = 6.0) -> np.ndarray:
    """The edge moved in and out along its length by smooth noise of about ``amplitude`` pixels
    (standard deviation), varying over ``scale`` pixels, as a careless brush or a coarse
    segmentation leaves it; the mask keeps its area."""
    from scipy import ndimage

    mask = np.asarray(mask, bool)
    noise = ndimage.gaussian_filter(rng.standard_normal(mask.shape), scale)
    noise *= amplitude / max(float(noise.std()), 1e-12)
    # The noisy distance's level set that keeps the mask's area: the edge moves out as much as in
    # (a fixed level would move it in by about half a pixel, the rim's distances being +1 and -1).
    value = (_signed_distance(mask) + noise).ravel()
    area = int(mask.sum())
    if area == 0:
        return mask.copy()
    level = np.partition(value, value.size - area)[value.size - area]
    return (value >= level).reshape(mask.shape)


def hole(mask: np.ndarray, share: float = 0.5) -> np.ndarray:
    """A round hole at the mask's deepest point, of radius ``share`` times that point's distance to
    the edge (a highlight or a label the segmentation left out)."""
    from scipy import ndimage

    mask = np.asarray(mask, bool)
    depth = ndimage.distance_transform_edt(mask)
    cy, cx = np.unravel_index(int(np.argmax(depth)), mask.shape)
    y, x = np.mgrid[:mask.shape[0], :mask.shape[1]]
    return mask & ((y - cy) ** 2 + (x - cx) ** 2 > (share * depth[cy, cx]) ** 2)


def drop_thin(mask: np.ndarray, width: float) -> np.ndarray:
    """The mask without its parts thinner than ``width`` pixels (a morphological opening by a disk
    of that diameter, then the largest piece alone): a handle, a pole or a thin branch the
    segmentation lost, and what it cut off with it."""
    from scipy import ndimage

    mask = np.asarray(mask, bool)
    opened = ndimage.binary_opening(mask, structure=_disk(width / 2))
    labels, n = ndimage.label(opened)
    if n <= 1:
        return opened
    sizes = ndimage.sum(opened, labels, index=np.arange(1, n + 1))
    return labels == 1 + int(np.argmax(sizes))


def extent(mask: np.ndarray) -> float:
    """The larger side (pixels) of the mask's bounding box."""
    rows, cols = np.nonzero(np.any(mask, 1))[0], np.nonzero(np.any(mask, 0))[0]
    return float(max(np.ptp(rows), np.ptp(cols)) + 1) if len(rows) else 0.0


REFERENCE_WIDTH = 256
"""Image width at which the degradations' pixel amounts hold; at other widths they scale with it."""

DEGRADATIONS = {
    "none": lambda m, rng, s: np.asarray(m, bool).copy(),
    "edge -4 px": lambda m, rng, s: shift_edge(m, -4 * s),
    "edge -2 px": lambda m, rng, s: shift_edge(m, -2 * s),
    "edge -1 px": lambda m, rng, s: shift_edge(m, -1 * s),
    "edge +1 px": lambda m, rng, s: shift_edge(m, 1 * s),
    "edge +2 px": lambda m, rng, s: shift_edge(m, 2 * s),
    "edge +4 px": lambda m, rng, s: shift_edge(m, 4 * s),
    "ragged 2 px": lambda m, rng, s: ragged_edge(m, 2.0 * s, rng, 6.0 * s),
    "hole": lambda m, rng, s: hole(m, 0.5),
    "thin part lost": lambda m, rng, s: drop_thin(m, 0.1 * extent(m)),
}
"""The degradations by name (pixels at :data:`REFERENCE_WIDTH`; the thin parts: under a tenth of
the object's larger side), each ``(mask, rng, scale) -> mask``, ``scale`` the image's width over
:data:`REFERENCE_WIDTH`."""


def degrade(mask: np.ndarray, name: str, rng: np.random.Generator) -> np.ndarray:
    """``mask`` degraded by the named entry of :data:`DEGRADATIONS`, its pixel amounts scaled to the
    mask's width (``ValueError`` for an unknown name; a degradation that empties the mask is an
    error, not a mask)."""
    if name not in DEGRADATIONS:
        raise ValueError(f"unknown mask degradation {name!r} (known: {', '.join(DEGRADATIONS)})")
    out = DEGRADATIONS[name](mask, rng, np.shape(mask)[1] / REFERENCE_WIDTH)
    if not out.any():
        raise ValueError(f"the degradation {name!r} leaves an empty mask")
    return out


def edge_shift(name: str) -> float | None:
    """The edge's shift in pixels (at :data:`REFERENCE_WIDTH`) of a degradation's name (``edge +2
    px``: 2), 0 for ``none``, None for the degradations that do not move the edge."""
    if name == "none":
        return 0.0
    if name.startswith("edge "):
        return float(name.split()[1])
    return None


def slug(name: str) -> str:
    """A degradation's name as a word for row ids and folders (``edge +2 px`` -> ``edgep2px``)."""
    return "".join(c for c in name.replace("+", "p").replace("-", "m").lower() if c.isalnum())


def by_slug(word: str) -> str:
    """The degradation whose :func:`slug` is ``word`` (``ValueError`` if none)."""
    for name in DEGRADATIONS:
        if slug(name) == word:
            return name
    raise ValueError(f"no mask degradation is called {word!r} (known: {', '.join(map(slug, DEGRADATIONS))})")


def degrade_views(src, dst, name: str, seed: int) -> list[float]:
    """A copy of the views folder ``src`` at ``dst`` (atomically) with every view's mask degraded
    by ``name`` (view i draws from ``seed`` and i), and ``degradation.json`` beside it (the name,
    the seed, each degraded mask's IoU with the true one, which it returns)."""
    import json
    import shutil
    from pathlib import Path

    from PIL import Image

    from ipm.errors import UserError
    from ipm.io import atomic_dir, write_json
    from ipm.io.views import save_mask
    from ipm.metrics.silhouette import view_ious

    src = Path(src)
    if not (src / "transforms.json").is_file():
        raise UserError(f"no views to degrade: {src / 'transforms.json'} is missing")
    ious = []
    with atomic_dir(dst) as tmp:
        shutil.copytree(src, tmp, dirs_exist_ok=True)
        for i, frame in enumerate(json.loads((tmp / "transforms.json").read_text())["frames"]):
            if "mask_path" not in frame:
                raise UserError(f"{src}: view {i} has no mask to degrade")
            path = tmp / frame["mask_path"]
            with Image.open(path) as img:
                mask = np.asarray(img.convert("L")) > 127
            try:
                out = degrade(mask, name, np.random.default_rng([seed, i]))
            except ValueError as exc:
                raise UserError(f"{src}: view {i}: {exc}") from None
            save_mask(path, out)
            ious.append(round(float(view_ious(mask[None], out[None])[0]), 4))
        write_json(tmp / "degradation.json", {"degradation": name, "seed": seed, "mask_iou": ious})
    return ious
