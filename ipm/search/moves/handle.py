"""The handle's side and turn: a part off the axis whose yaw one view's outline leaves open, told by
the colour image's shading.

One view's outline barely tells a cup's handle towards the camera from its mirror behind the body,
nor a handle turned a little more from one turned less (the fit makes its ring wider or narrower to
match). The move mirrors the fit's ``Generator.sided_part`` through the vertical plane across the
line of sight (a turn of the yaw) and gives the mirror Adam steps; where the outline does not tell
the two apart it tries both turned by ``handle_side_turns`` too, and of the candidates whose loss
lies within the tolerance of the lowest keeps the one whose surface shades most like the photo
(docs/decisions.md, "The handle's side and turn by the image's shading").
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ipm.search.moves.base import Move, register
from ipm.settings import Range, Settings, at_least

NEAR_PX = 2
"""Pixels within this many of the mask's rim say nothing of the shading (they mix object and backdrop)."""
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
"""Linear RGB to luminance (Rec. 709)."""


@dataclass(frozen=True)
class HandleSideSettings(Settings):
    """Settings of the ``handle side`` move."""

    KIND = "diff setting"
    handle_side: bool = True
    """Try the sided part's mirror behind or in front of the body, and turns of both, and let the
    colour image's shading choose (one view with a colour image; docs/decisions.md, "The handle's
    side and turn by the image's shading")."""
    handle_side_steps: Annotated[int, at_least(0)] = 80
    """Adam steps each candidate gets at the last stage's width before they are compared."""
    handle_side_tolerance: Annotated[float, at_least(0.0)] = 0.05
    """Candidates whose loss is at most this share above the lowest are ties the shading decides:
    beyond it the outline itself tells them apart (set beforehand, not tuned)."""
    handle_side_turns: tuple[Annotated[float, Range(-180.0, 180.0)], ...] = (-45.0, -30.0, -15.0, 15.0, 30.0, 45.0)
    """Turns of the yaw (degrees) given to the fit and to its mirror where the outline does not
    tell the two apart."""


def mirrored_yaw(problem, z: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """``z`` turned about its vertical axis so that its object-frame +x (where a sided part lies)
    is reflected through the vertical plane across the line of sight from ``c2w``'s centre."""
    o, up, x = problem.to_world(z)(np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    a = (up - o) / np.linalg.norm(up - o)
    h, v = x - o, c2w[:3, 3] - o
    h, v = h - (h @ a) * a, v - (v @ a) * a
    v /= max(np.linalg.norm(v), 1e-12)
    h2 = h - 2.0 * (h @ v) * v
    return problem.turned(z, np.arctan2(a @ np.cross(h, h2), h @ h2))


def surface_maps(problem, z: np.ndarray, lod: int, views) -> tuple[np.ndarray, np.ndarray]:
    """``z``'s mesh in the one view: per pixel the normal of the face its ray meets first (H, W, 3)
    and that face's part (H, W; -1 where the ray misses)."""
    from ipm.render.raycast import mesh_scene, pixel_hits

    mesh = problem.world_mesh(z, lod)
    # the views' c2w sees problem.vertex_fn's vertices; world_mesh's are the same where the camera is known
    verts = mesh.vertices if problem.camera is None else np.asarray(
        problem.vertex_fn(problem.key(z), lod)(np.asarray(z, np.float32)), np.float64).reshape(-1, 3)
    _, face = pixel_hits(mesh_scene(verts, mesh.faces), views.c2w[0], views.fov_x, views.width, views.height)
    e1, e2 = (verts[mesh.faces[:, k]] - verts[mesh.faces[:, 0]] for k in (1, 2))
    normals = np.cross(e1, e2)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    hit = face >= 0
    return np.where(hit[..., None], normals[np.maximum(face, 0)], 0.0), np.where(hit, mesh.labels[np.maximum(face, 0)], -1)


def harmonics(n: np.ndarray) -> np.ndarray:
    """The nine real spherical harmonics up to the second order (unnormalised) of unit vectors n (N, 3)."""
    x, y, z = n.T
    return np.stack([np.ones_like(x), x, y, z, x * y, y * z, x * z, 3.0 * z * z - 1.0, x * x - y * y], 1)


def shading_residuals(luminance: np.ndarray, mask: np.ndarray, maps: list[tuple[np.ndarray, np.ndarray]]) -> list[float]:
    """For each candidate's :func:`surface_maps`, how far the photo's ``luminance`` (H, W, linear)
    is from a shading of its surface: over the pixels of the ``mask`` (less :data:`NEAR_PX` of its
    rim and a pixel more) that every candidate covers, per part the luminance fitted by
    second-order spherical harmonics of the normals (any distant lighting, the part's albedo folded
    in), the fits' residuals pooled (root mean square)."""
    from scipy.ndimage import binary_erosion

    common = binary_erosion(mask > 0.5, iterations=NEAR_PX + 1)
    for _, part in maps:
        common &= part >= 0
    if not common.any():
        return [0.0] * len(maps)
    y = luminance[common]
    out = []
    for normals, part in maps:
        n, p = normals[common], part[common]
        sq = 0.0
        for k in np.unique(p):
            a, b = harmonics(n[p == k]), y[p == k]
            coef, *_ = np.linalg.lstsq(a, b, rcond=None)
            sq += float(((b - a @ coef) ** 2).sum())
        out.append(float(np.sqrt(sq / len(y))))
    return out


@register
class HandleSide(Move):
    """The sided part's mirror and turns tried and chosen by the colour image's shading (one view; see the module)."""

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
        score, steps, tol = trial.scorer((10_003, 10_004)), settings.handle_side_steps, settings.handle_side_tolerance
        loss = score(cand.z)
        trial.record("fit", loss)
        mirror = mirrored_yaw(problem, cand.z, views.c2w[0])
        alt, loss_alt = trial.tried(mirror, "mirror", steps, score)
        if loss_alt > (1.0 + tol) * loss:
            return cand  # the outline tells the sides apart
        turns = [(f"{name} turned {turn:+g} deg", problem.turned(base, np.radians(turn)))
                 for name, base in (("fit", cand.z), ("mirror", mirror)) for turn in settings.handle_side_turns]
        tried = [("fit", cand.z, loss), ("mirror", alt, loss_alt)] + [
            (tag, *t) for (tag, _), t in zip(turns, trial.tries([(start, tag, steps, score) for tag, start in turns]))]
        lowest = min(t[2] for t in tried)
        ties = [t for t in tried if t[2] <= (1.0 + tol) * lowest]
        if len(ties) == 1:
            name, z, kept = ties[0]
            trial.record(f"{name} kept: the outline decides", kept)
        else:
            maps = [surface_maps(problem, z, lod, views) for _, z, _ in ties]
            residuals = shading_residuals(photos[0] @ LUMINANCE, views.masks[0], maps)
            k = int(np.argmin(residuals))
            name, z, kept = ties[k]
            trial.record(f"{name} kept: shading residual {residuals[k]:.4f} of {len(ties)} ties "
                         f"(worst {max(residuals):.4f})", kept)
        cand.z = z
        return cand
