"""The handle's side: a part off the axis in front of the body or behind it, told by the colour image.

One view's outline barely tells a cup's handle towards the camera from its mirror behind the body;
the colour image does: a handle in front draws its outline across the body, a handle behind is cut
by the body's outline. The move mirrors the fit's ``Generator.sided_part`` through the vertical
plane across the line of sight (a turn of the yaw), gives the mirror Adam steps, and where the
outline does not tell them apart keeps the one whose edges between part and body lie on the
stronger image gradient (docs/decisions.md, "The handle's side by the image's edges").
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.search.moves.base import Move, register
from ipm.settings import Settings, at_least

DEPTH_JUMP = 0.03
"""Neighbouring pixels whose ray distances differ by more than this share lie across a depth edge."""
NEAR_PX = 2
"""Pixels within this many of the outline or of a join (and one more) say nothing of the side."""


@dataclass(frozen=True)
class HandleSideSettings(Settings):
    """Settings of the ``handle side`` move."""

    KIND = "diff setting"
    handle_side: bool = True
    """Try the sided part's mirror behind or in front of the body and let the colour image choose
    (one view with a colour image; docs/decisions.md, "The handle's side by the image's edges")."""
    handle_side_steps: Annotated[int, at_least(0)] = 80
    """Adam steps the mirror gets at the last stage's width before the two are compared."""
    handle_side_tolerance: Annotated[float, at_least(0.0)] = 0.05
    """The mirror is a candidate where its loss is at most this share above the fit's: beyond it
    the outline itself tells the sides apart (set beforehand, not tuned)."""


def mirrored_yaw(problem, z: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """``z`` turned about its vertical axis so that its object-frame +x (where a sided part lies)
    is reflected through the vertical plane across the line of sight from ``c2w``'s centre."""
    o, up, x = problem.to_world(z)(np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    a = (up - o) / np.linalg.norm(up - o)
    h, v = x - o, c2w[:3, 3] - o
    h, v = h - (h @ a) * a, v - (v @ a) * a
    v /= max(np.linalg.norm(v), 1e-12)
    h2 = h - 2.0 * (h @ v) * v
    out = np.array(z, np.float64)
    out[problem.n_shape] += np.arctan2(a @ np.cross(h, h2), h @ h2)
    return problem.clip(out)


def part_edges(t: np.ndarray, on_part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the sided part meets the rest of the object in the image (H, W each): of two
    neighbouring pixels that both hit the mesh, one on the part and one off it, the edges (their
    ray distances differ by more than :data:`DEPTH_JUMP` of the nearer: one in front of the
    other) and the joins (they do not: where the part is attached)."""
    edges, joins = np.zeros(t.shape, bool), np.zeros(t.shape, bool)
    hit = np.isfinite(t)
    for axis in (0, 1):
        ta, tb = np.swapaxes(t, 0, axis)[:-1], np.swapaxes(t, 0, axis)[1:]
        pa, pb = np.swapaxes(on_part, 0, axis)[:-1], np.swapaxes(on_part, 0, axis)[1:]
        meet = np.swapaxes(hit, 0, axis)[:-1] & np.swapaxes(hit, 0, axis)[1:] & (pa != pb)
        jump = np.abs(np.where(meet, ta - tb, 0.0)) > DEPTH_JUMP * np.where(meet, np.minimum(ta, tb), 0.0)
        for out, pairs in ((edges, meet & jump), (joins, meet & ~jump)):
            o = np.swapaxes(out, 0, axis)
            o[:-1] |= pairs
            o[1:] |= pairs
    return edges, joins


def image_gradient(photo: np.ndarray) -> np.ndarray:
    """Sobel gradient (H, W, 2: along x, along y) of the photo's luminance."""
    from scipy.ndimage import sobel

    grey = np.asarray(photo, np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    return np.stack([sobel(grey, 1), sobel(grey, 0)], -1)


def edge_maps(problem, z: np.ndarray, lod: int, views) -> tuple[np.ndarray, ...]:
    """``z`` in the one view (H, W each): its sided part's edges and joins (:func:`part_edges`),
    the pixels the part covers and those the object covers."""
    from ipm.render.raycast import mesh_scene, pixel_hits

    mesh = problem.world_mesh(z, lod)
    # the views' c2w sees problem.vertex_fn's vertices; world_mesh's are the same where the camera is known
    verts = mesh.vertices if problem.camera is None else np.asarray(
        problem.vertex_fn(problem.key(z), lod)(np.asarray(z, np.float32)), np.float64).reshape(-1, 3)
    t, face = pixel_hits(mesh_scene(verts, mesh.faces), views.c2w[0], views.fov_x, views.width, views.height)
    on_part = (face >= 0) & (mesh.labels[np.maximum(face, 0)] == mesh.part_names.index(problem.generator.sided_part))
    return (*part_edges(t, on_part), on_part, face >= 0)


def edge_strengths(gradient: np.ndarray, maps: list[tuple[np.ndarray, ...]]) -> list[float]:
    """For each candidate's :func:`edge_maps`, the mean strength of the image ``gradient`` across
    its part's edges (along the part outline's normal, the largest within a pixel: an edge one
    pixel off still counts), leaving out the outline and the joins of every candidate (by
    :data:`NEAR_PX` and a pixel more: their gradients say nothing of the side). A candidate that
    draws no edge there says the image is as elsewhere inside the object: it scores the mean
    gradient magnitude there (the largest within a pixel too)."""
    from scipy.ndimage import binary_dilation, binary_erosion, gaussian_filter, maximum_filter, sobel

    inside = binary_erosion(np.logical_and.reduce([m[3] for m in maps]), iterations=NEAR_PX + 1)
    keep = inside & ~binary_dilation(np.logical_or.reduce([m[1] for m in maps]), iterations=NEAR_PX + 1)
    if not keep.any():
        return [0.0] * len(maps)
    typical = float(maximum_filter(np.linalg.norm(gradient, axis=-1), size=3)[keep].mean())
    out = []
    for edges, _, part, _ in maps:
        soft = gaussian_filter(part.astype(np.float64), 1.0)
        normal = np.stack([sobel(soft, 1), sobel(soft, 0)], -1)
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True) + 1e-12
        across = np.abs((gradient * normal).sum(-1))
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                shifted = np.abs((np.roll(gradient, (dy, dx), (0, 1)) * normal).sum(-1))
                across = np.maximum(across, shifted)
        on = edges & keep
        out.append(float(across[on].mean()) if on.any() else typical)
    return out


@register
class HandleSide(Move):
    """The sided part's mirror tried and chosen by the colour image (one view; see the module)."""

    name, phase, settings = "handle side", "end", HandleSideSettings

    def applies(self, problem, profile) -> bool:
        return profile.of(HandleSideSettings).handle_side and problem.generator.sided_part is not None

    def cost(self, problem, profile) -> int:
        return profile.of(HandleSideSettings).handle_side_steps

    def __call__(self, cand, trial, settings):
        from ipm.io.views import load_photos

        problem, views = trial.problem, trial.views
        if views is None or len(views.c2w) != 1 or not views.posed:
            return cand
        lod = max(trial.profile.loop.refine_lod, problem.generator.min_fit_lod)
        mesh = problem.world_mesh(cand.z, lod)
        if not (mesh.labels == mesh.part_names.index(problem.generator.sided_part)).any():
            return cand
        photos = load_photos(views)
        if photos is None:
            return cand
        gradient = image_gradient(photos[0])
        score = trial.scorer((10_003, 10_004))
        loss = score(cand.z)
        trial.record("fit", loss)
        alt, loss_alt = trial.tried(mirrored_yaw(problem, cand.z, views.c2w[0]), "mirror",
                                    settings.handle_side_steps, score)
        if loss_alt > (1.0 + settings.handle_side_tolerance) * loss:
            return cand
        maps = [edge_maps(problem, z, lod, views) for z in (cand.z, alt)]
        kept, other = edge_strengths(gradient, maps)
        chosen = other > kept
        trial.record(f"{'mirror' if chosen else 'fit'} kept: image edges {other:.4f} (mirror) "
                     f"vs {kept:.4f} (fit)", loss_alt if chosen else loss)
        if chosen:
            cand.z = alt
        return cand
