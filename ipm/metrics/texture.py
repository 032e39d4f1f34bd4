"""Appearance scores of a textured result (``docs/design``, "The metric"): the result rendered by
Mitsuba under the reference lighting against the reference's colour views, masked PSNR and SSIM
(scikit-image) in sRGB over the reference's object pixels, on the input views and on the views of
the half of the sphere the input sees and of the half it does not."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ipm.errors import UserError

SIDES = ("input", "seen", "unseen")
"""Where a view looks from: an input view; the half of the sphere round the object that the
inputs' mean direction points into; the other half."""


def sides(c2w: np.ndarray, centre: np.ndarray, n_input: int) -> list[str]:
    """Each view's side (:data:`SIDES`): the first ``n_input`` are the inputs; another view is
    ``seen`` when its direction from ``centre`` is within 90 degrees of the inputs' mean one."""
    to_cam = c2w[:, :3, 3] - centre
    to_cam /= np.maximum(np.linalg.norm(to_cam, axis=1, keepdims=True), 1e-12)
    mean = to_cam[:n_input].mean(0)
    return ["input" if i < n_input else "seen" if to_cam[i] @ mean > 0 else "unseen" for i in range(len(c2w))]


def masked_scores(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> dict:
    """PSNR (dB) and SSIM of ``image`` against ``reference`` (h, w, 3) sRGB in [0, 1] over ``mask``'s
    pixels (SSIM: scikit-image's map on the whole image, averaged over them)."""
    from skimage.metrics import structural_similarity

    m = np.asarray(mask) > 0.5
    if not m.any():
        raise UserError("an empty reference mask has no pixels to score")
    mse = float(np.mean((image[m] - reference[m]) ** 2))
    psnr = float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)
    _, ssim_map = structural_similarity(image, reference, channel_axis=-1, data_range=1.0, full=True)
    return {"psnr": psnr, "ssim": float(ssim_map[m].mean())}


def render_textured(run: str | Path, views, spp: int = 64) -> np.ndarray:
    """Linear RGB renders (n, H, W, 3) of a textured result (its folder's mesh.glb, world frame) by
    Mitsuba under the reference lighting from every camera of ``views`` (``ipm.io.views.Views``)."""
    from ipm.render.textured import render_glb

    return render_glb(Path(run) / "mesh.glb", views.c2w, views.fov_x, views.width, views.height, spp)


def look_at_centre(c2w: np.ndarray) -> np.ndarray:
    """The point nearest to every camera's optical axis (least squares; the object's centre for
    views that orbit it)."""
    a, b = np.zeros((3, 3)), np.zeros(3)
    for m in c2w:
        d = -m[:3, 2] / np.linalg.norm(m[:3, 2])
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ m[:3, 3]
    return np.linalg.lstsq(a, b, rcond=None)[0]


def score_result(run: str | Path, views_path: str | Path,
                 appearance: str = "ipm.metrics.texture:render_textured") -> dict:
    """A result (its folder) rendered by ``appearance`` (``module:function(run, views)`` -> linear
    RGB (n, H, W, 3): a method's :attr:`ipm.methods.Method.appearance`) and scored against every view
    of ``views_path`` (the reference's colour views under the reference lighting, view 0 the
    input view): per view its side and scores, and the mean per side."""
    from ipm.io.views import load_views
    from ipm.methods import resolve

    views = load_views(views_path)
    if views.lighting != "reference":
        raise UserError(f"{views_path}: scores need colour views under the reference lighting")
    return score_renders(resolve(appearance)(run, views), views)


def score_renders(renders: np.ndarray, views) -> dict:
    """Linear renders (n, H, W, 3) scored against the colour views ``views`` (``ipm.io.views.Views``,
    view 0 the input view): per view its side (:func:`sides`, from the input view) and scores, and
    the mean per side."""
    from ipm.io.views import load_photos, srgb_bytes

    reference = load_photos(views)
    side = sides(views.c2w, look_at_centre(views.c2w), 1)
    per_view = []
    for i in range(len(views)):
        got, want = srgb_bytes(renders[i]) / 255.0, srgb_bytes(reference[i]) / 255.0
        per_view.append({"view": i, "side": side[i], **masked_scores(got, want, views.masks[i])})
    means = {s: {k: float(np.mean([v[k] for v in per_view if v["side"] == s])) for k in ("psnr", "ssim")}
             for s in SIDES if any(v["side"] == s for v in per_view)}
    return {"views": per_view, "sides": means}
