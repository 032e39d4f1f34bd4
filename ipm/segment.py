"""Masks from the image: for an object photographed on a plain background, by colour alone (no
model weights, :func:`mask_from_image`); for a photograph with a ground, a shadow and a backdrop,
by the learned segmenter refined by GrabCut (:func:`mask_from_photo`).

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

SURE = 0.02
"""Learned probabilities below this (above one minus it) fix a pixel as background (object) for GrabCut."""
RELEASE = True
"""Whether :func:`mask_from_photo` lets the object's colours release what the network took for
ground (:func:`_released`; docs/decisions.md, "The object's colours release what the network took
for ground")."""
RELEASE_REACH = 0.75
"""How far from the mask (times the square root of its area) a pixel may be released; the ground's
colours are taken beyond it (less what is joined to the object: ``_joined``)."""
CROP = 0.5
"""Where the network's object (its probability above 0.5) spans, enlarged by half, less than this
share of the photo's shorter side, :func:`mask_from_photo` segments the photo again cropped to a
square about it (:func:`_crop_box`): the network reads photos at 128 px, where a small object is a
few pixels across (docs/decisions.md, "A small object cropped")."""
BORDER = 0.02
"""Width of the border frame whose colours are the background's (times the image's shorter side)."""
MARGIN = 2.0
"""A pixel is object where its distance to the background model is this many times the distance
all but 0.5 % of the border stays under (at least 1: one CIELAB unit on a flat background)."""
SEGMENT_PX = 512
"""A photo longer than this on its long side is segmented by :func:`mask_from_photo` at this size
(area averaged) and its mask enlarged back (:func:`_segmented`): GrabCut's time grows with the
pixels (a 12-megapixel phone photo took 90 s). The colour model of the border keeps every pixel
(docs/decisions.md, "Segmenting a large photo")."""


def _frame(shape: tuple[int, ...]) -> np.ndarray:
    """Boolean (H, W): the image's border frame, :data:`BORDER` of its shorter side wide (at least 2 px)."""
    h, w = shape[:2]
    width = max(2, int(round(BORDER * min(h, w))))
    frame = np.zeros((h, w), bool)
    frame[:width] = frame[-width:] = True
    frame[:, :width] = frame[:, -width:] = True
    return frame


def _rgb(rgb) -> np.ndarray:
    """``rgb`` as an array, ``UserError`` unless it is an RGB(A) image of at least 16 x 16."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] < 3 or min(rgb.shape[:2]) < 16:
        raise UserError(f"cannot segment an image of shape {rgb.shape}: needs an RGB image of at least 16 x 16")
    return rgb


def _distance(pixels: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Mahalanobis distance of ``pixels`` (..., 3) to the Gaussian of ``sample`` (k, 3)."""
    mean = sample.mean(0)
    cov = np.cov(sample.T) + np.eye(3) * 1.0  # 1 Lab unit of floor: a flat render's border has none
    d = pixels - mean
    return np.sqrt(np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d))


def _border_model(rgb: np.ndarray) -> tuple[np.ndarray, float]:
    """Each pixel's distance (H, W) to the background model of the image's border and the distance
    that counts as object (:data:`MARGIN` times the border's own 99.5th percentile); ``UserError``
    for an image that is not RGB or when nothing stands out."""
    from skimage.color import rgb2lab

    rgb = _rgb(rgb)
    img = rgb[..., :3].astype(np.float64) / (255.0 if rgb.dtype == np.uint8 else 1.0)
    lab = rgb2lab(np.clip(img, 0.0, 1.0))
    border = lab[_frame(lab.shape)]
    d_border = _distance(border, border)
    border = border[d_border <= np.quantile(d_border, 0.9)]  # the object where it touches the edge
    dist = _distance(lab, border)
    threshold = MARGIN * max(float(np.quantile(_distance(border, border), 0.995)), 1.0)
    if dist.max() <= threshold:
        raise UserError("no object stands out from the colours at the image's border: give a mask")
    return dist, threshold


def _cleaned(mask: np.ndarray) -> np.ndarray:
    """``mask`` without specks and small holes (large ones stay), keeping the components of at
    least 5 % of the largest; float32 in {0, 1}; ``UserError`` if nothing is left."""
    from skimage.measure import label
    from skimage.morphology import disk, opening, remove_small_holes, remove_small_objects

    area = mask.size
    mask = opening(mask, disk(1))
    mask = remove_small_objects(mask, max_size=max(4, int(1e-4 * area)))
    mask = remove_small_holes(mask, max_size=max(4, int(1e-3 * area)))
    labels = label(mask)
    if labels.max() == 0:
        raise UserError("no object stands out from the colours at the image's border: give a mask")
    sizes = np.bincount(labels.ravel())[1:]
    keep = np.nonzero(sizes >= 0.05 * sizes.max())[0] + 1
    return np.isin(labels, keep).astype(np.float32)


def mask_from_image(rgb: np.ndarray) -> np.ndarray:
    """Object mask (H, W) float32 in {0, 1} of an RGB image (H, W, 3; uint8, or float in [0, 1])
    whose border shows the background; ``UserError`` when nothing stands out from it."""
    dist, threshold = _border_model(rgb)
    return _cleaned(dist > threshold)


def mask_from_photo(rgb: np.ndarray, model=None, release: bool | None = None, crop: bool = True) -> np.ndarray:
    """Object mask (H, W) float32 in {0, 1} of a photograph (H, W, 3; uint8, or float in [0, 1]):
    the learned segmenter's probability (``ipm.learned.segmenter``, ``model`` or the shipped one:
    it tells the object from its ground, shadow and backdrop) starts OpenCV's GrabCut (the confident
    object and background fixed, the rest probable), which sets the edges at the photo's size (at
    most :data:`SEGMENT_PX`); with ``release`` (default :data:`RELEASE`) the object's colours then
    take back confident background that looks like it (:func:`_released`); with ``crop``, a small
    object is segmented in a crop about it, taken at the photo's full size (:data:`CROP`)."""
    from ipm.learned.segmenter import probability

    rgb = _rgb(rgb)
    img8 = np.ascontiguousarray(rgb[..., :3] if rgb.dtype == np.uint8 else
                                np.clip(rgb[..., :3] * 255 + 0.5, 0, 255).astype(np.uint8))
    release = RELEASE if release is None else release
    prob = probability(img8, model) if crop else None
    box = None if prob is None else _crop_box(prob > 0.5)
    if box is None:
        return _segmented(img8, model, release, prob)
    (y0, y1), (x0, x1) = box  # the object again, cropped to it, and nothing beyond the crop
    mask = np.zeros(img8.shape[:2], np.float32)
    mask[y0:y1, x0:x1] = _segmented(np.ascontiguousarray(img8[y0:y1, x0:x1]), model, release)
    return mask


def _segmented(img8: np.ndarray, model, release: bool, prob: np.ndarray | None = None) -> np.ndarray:
    """:func:`mask_from_photo`'s mask of an 8-bit photo as it is: the network's probability (``prob``
    where already read off this photo), GrabCut from it and the release; a photo longer than
    :data:`SEGMENT_PX` shrunk to it first and its mask enlarged back."""
    import cv2

    from ipm.learned.segmenter import probability

    h, w = img8.shape[:2]
    scale = SEGMENT_PX / max(h, w)
    if scale < 1.0:
        small = cv2.resize(img8, (max(16, round(w * scale)), max(16, round(h * scale))), interpolation=cv2.INTER_AREA)
        mask = _segmented(small, model, release)
        return (cv2.resize(mask, (w, h), interpolation=cv2.INTER_LINEAR) > 0.5).astype(np.float32)
    prob = probability(img8, model) if prob is None else prob
    gc = np.select([prob < SURE, prob > 1 - SURE, prob > 0.5], [cv2.GC_BGD, cv2.GC_FGD, cv2.GC_PR_FGD],
                   cv2.GC_PR_BGD).astype(np.uint8)
    if not (gc == cv2.GC_FGD).any() and not (gc == cv2.GC_PR_FGD).any():
        raise UserError("the segmenter finds no object in the photo: give a mask")
    mask = _grab_cut(img8, gc)
    return _released(img8, gc, mask) if release else mask


def _crop_box(obj: np.ndarray) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """The rows and columns (start, stop) of a square about the pixels of ``obj`` (H, W) bool, 1.5
    times their box's longer side, clipped to the image; None where there are none or the square
    is not smaller than :data:`CROP` of the image's shorter side."""
    if not obj.any():
        return None
    h, w = obj.shape
    rows, cols = np.nonzero(obj.any(1))[0], np.nonzero(obj.any(0))[0]
    side = 1.5 * max(rows[-1] + 1 - rows[0], cols[-1] + 1 - cols[0])
    if side >= CROP * min(h, w):
        return None
    side = max(side, 16.0)
    cy, cx = (rows[0] + rows[-1] + 1) / 2, (cols[0] + cols[-1] + 1) / 2
    span = lambda c, n: (max(0, int(round(c - side / 2))), min(n, int(round(c + side / 2))))  # noqa: E731
    return span(cy, h), span(cx, w)


def _grab_cut(img8: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """OpenCV's GrabCut from GrabCut ``labels`` (left as they were), its mask cleaned."""
    import cv2

    gc = labels.copy()
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)
    cv2.grabCut(img8, gc, None, bgd, fgd, 5, cv2.GC_INIT_WITH_MASK)
    return _cleaned((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD))


def _released(img8: np.ndarray, labels: np.ndarray, mask: np.ndarray, passes: int = 2) -> np.ndarray:
    """``mask`` grown by the confident background (``labels``) that looks like the object: twice,
    the object's chroma (five k-means centres of CIELAB a, b over the mask; a shadow on the ground
    barely changes it) against the ground's (eight over the confident background beyond
    :data:`RELEASE_REACH`, less the object's far parts: :func:`_joined`); a pixel within reach
    nearer the object's than half its distance to the ground's becomes probable object, and
    GrabCut runs again from the labels so changed."""
    import cv2
    from scipy.ndimage import binary_dilation

    ab = cv2.cvtColor(img8, cv2.COLOR_RGB2LAB).reshape(-1, 3)[:, 1:].astype(np.float32)
    ground, frame = labels == cv2.GC_BGD, _frame(labels.shape)
    stop = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)

    def centres(pixels: np.ndarray, k: int) -> np.ndarray | None:
        if len(pixels) < k:
            return None
        cv2.setRNGSeed(0)
        return cv2.kmeans(pixels, k, None, stop, 2, cv2.KMEANS_PP_CENTERS)[2]

    def nearest(c: np.ndarray) -> np.ndarray:
        return np.linalg.norm(ab[:, None] - c[None], axis=2).min(1).reshape(mask.shape)

    for _ in range(passes):
        inside = mask > 0.5
        near = binary_dilation(inside, iterations=max(int(RELEASE_REACH * np.sqrt(inside.sum())), 1))
        obj, edge = centres(ab[inside.ravel()], 5), centres(ab[(ground & ~near & frame).ravel()], 8)
        if obj is None or edge is None:
            return mask
        d_obj = nearest(obj)
        bg = centres(ab[(ground & ~near & ~_joined(inside, d_obj < 0.5 * nearest(edge))).ravel()], 8)
        if bg is None:
            return mask
        gc = labels.copy()
        gc[ground & near & (d_obj < 0.5 * nearest(bg))] = cv2.GC_PR_FGD
        mask = _grab_cut(img8, gc)
    return mask


def _joined(inside: np.ndarray, like: np.ndarray) -> np.ndarray:
    """The pixels outside ``inside`` joined to it (8-connected) through pixels where ``like`` holds:
    a part of the object beyond the release's reach (a glass's foot below its stem), kept out of
    the ground's colours."""
    from scipy.ndimage import label

    parts, _ = label(like | inside, structure=np.ones((3, 3)))
    ids = np.unique(parts[inside])
    return np.isin(parts, ids[ids > 0]) & ~inside
