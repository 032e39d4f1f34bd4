"""The texture stage: a result's parts painted from the input photographs on the generator's UVs
(``docs/design``, "The texture stage").

1. Projection: each texel's surface point takes the colour of every input view that sees it (a
   ray from the camera meets the fitted mesh there first), divided by the shading the reference
   lighting gives a white mesh at that pixel, so the texture holds albedo; views weigh by how
   squarely they see the point and how well it is lit. Further passes (``SHADING_PASSES``)
   divide by the shading the painted mesh itself gets (its render over its albedo), so that light
   bounced between its parts is that of their painted colours, not of white.
2. Fill: a texel no view sees takes the mean of the seen texels of its symmetry group (the
   generator's ``texture_symmetry``: a dish's rows round its axis), else its part's mean.
3. Refinement (under the reference lighting): Mitsuba's differentiable renderer and Adam fit a
   correction of the textures to the input views, coarse to fine (:func:`refine`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ipm.errors import UserError
from ipm.render.raycast import mesh_scene
from ipm.uv import Texels, pad, texels

TEXTURE_RES = 256
"""Texels across a part's square texture."""
MIN_SHADING = 0.05
"""Shading (a white mesh's linear radiance) under which a pixel says too little of the albedo."""


@dataclass(frozen=True)
class Refinement:
    """The refinement's schedule: per stage the resolution of the correction it fits (bilinearly
    enlarged onto the texture) and its steps (one input view each, in turn); Adam's rate and
    Mitsuba's samples a pixel."""

    stages: tuple[tuple[int, int], ...] = ((64, 20), (256, 20))
    lr: float = 0.02
    spp: int = 8


SHADING_PASSES = 3
"""Projections under the reference lighting: each after the first divides the photos by the
painted mesh's own shading, its render under the lighting over the albedo each pixel sees, from
the last pass's textures (docs/decisions.md, "Shading of the painted mesh")."""

REFINEMENT: Refinement | None = None
"""The diff path's refinement (docs/decisions.md, "Texture refinement"; None: projection and fill
alone)."""


def _bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``image`` (H, W[, channels]) at pixel positions ``xy`` (N, 2) (x right, y down, centres at +0.5)."""
    from ipm.io.lens import sample_image

    return sample_image(np.asarray(image, np.float64)[None], xy[None, :, 0] - 0.5, xy[None, :, 1] - 0.5, False)[0, 0]


def visible(scene, origin: np.ndarray, points: np.ndarray, tolerance: float) -> np.ndarray:
    """Whether each point (N, 3) is the first surface a ray from ``origin`` meets (within
    ``tolerance`` of its distance), by Mitsuba's ray casts on ``scene``."""
    import mitsuba as mi

    d = points - origin
    dist = np.linalg.norm(d, axis=1)
    d /= np.maximum(dist[:, None], 1e-12)
    o = np.broadcast_to(origin, d.shape).astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(*(o[:, i] for i in range(3))), mi.Vector3f(*(d[:, i].astype(np.float32)
                                                                          for i in range(3))))
    si = scene.ray_intersect(ray)
    t = np.array(si.t)
    return np.isfinite(t) & (t >= dist - tolerance)


def sightings(mesh, part: int, masks: np.ndarray, c2w: np.ndarray, fov_x: float, res: int = TEXTURE_RES,
              scene=None) -> tuple[Texels, list]:
    """Part ``part``'s covered texels and, per view, those it sees: facing it, the first surface a
    ray from its camera meets and wholly inside its mask (not on the rim), as (view index, texel
    indices, their pixel positions, the cosines at them). What the photos' shading does not change,
    found once for every projection."""
    from ipm.render.cameras import project as to_pixels

    sel = mesh.labels == part
    tx = texels(mesh.vertices, mesh.faces[sel], mesh.uv[sel], res)
    scene = mesh_scene(mesh.vertices, mesh.faces) if scene is None else scene
    size = float(np.linalg.norm(np.ptp(mesh.vertices, 0)))
    h, w = masks.shape[1:3]
    seen_by = []
    for view, (mask, cam) in enumerate(zip(masks, c2w)):
        origin = cam[:3, 3]
        towards = origin - tx.points
        cos = np.einsum("nj,nj->n", tx.normals, towards) / np.maximum(np.linalg.norm(towards, axis=1), 1e-12)
        xy = to_pixels(tx.points, cam, fov_x, w, h)
        inside = (cos > 0.1) & (xy[:, 0] >= 1) & (xy[:, 0] <= w - 1) & (xy[:, 1] >= 1) & (xy[:, 1] <= h - 1)
        idx = np.flatnonzero(inside)
        if len(idx) == 0:
            continue
        idx = idx[visible(scene, origin, tx.points[idx], 2e-3 * size)]
        idx = idx[_bilinear(_eroded(mask), xy[idx]) > 0.99]  # a pixel wholly the object's, not its edge
        seen_by.append((view, idx, xy[idx], cos[idx]))
    return tx, seen_by


def project(tx: Texels, seen_by: list, photos: np.ndarray, shading: np.ndarray,
            res: int = TEXTURE_RES) -> tuple[np.ndarray, np.ndarray]:
    """A part's texture (res, res, 3) linear albedo from the photos (n, H, W, 3) linear and the
    mesh's shading in them ((n, H, W), or per channel (n, H, W, 3)) at the texels the views see
    (:func:`sightings`), and the weight each texel got (0: no view saw it)."""
    total, weight = np.zeros((len(tx.points), 3)), np.zeros(len(tx.points))
    for view, idx, xy, cos in seen_by:
        lit = _bilinear(shading[view], xy)
        lit = lit[:, None] if lit.ndim == 1 else lit
        ok = lit.mean(1) > MIN_SHADING
        idx, xy, lit = idx[ok], xy[ok], lit[ok]
        wgt = cos[ok] * lit.mean(1)
        total[idx] += wgt[:, None] * _bilinear(photos[view], xy) / lit
        weight[idx] += wgt
    texture = np.zeros((res, res, 3))
    seen = np.zeros((res, res))
    texture[tx.rows, tx.cols] = total / np.maximum(weight, 1e-12)[:, None]
    seen[tx.rows, tx.cols] = weight
    return texture, seen


def _eroded(mask: np.ndarray) -> np.ndarray:
    """The mask less its one-pixel rim (a rim pixel mixes the object with what is behind it)."""
    from scipy.ndimage import binary_erosion

    return binary_erosion(mask > 0.5, iterations=1).astype(np.float64)


def fill(texture: np.ndarray, seen: np.ndarray, covered: tuple[np.ndarray, np.ndarray],
         groups: np.ndarray | None) -> np.ndarray:
    """``texture`` with every covered texel (rows, cols) no view saw filled: the mean of its
    symmetry group's seen texels (``groups`` (res, res) ints, -1 none), else the part's seen mean
    (mid grey where nothing of the part was seen)."""
    out = texture.copy()
    rows, cols = covered
    known = seen[rows, cols] > 0
    mean = texture[rows[known], cols[known]].mean(0) if known.any() else np.full(3, 0.5)
    todo = ~known
    if groups is not None and known.any():
        g = groups[rows, cols]
        labels, inverse = np.unique(g, return_inverse=True)
        sums = np.zeros((len(labels), 3))
        counts = np.zeros(len(labels))
        np.add.at(sums, inverse[known], texture[rows[known], cols[known]])
        np.add.at(counts, inverse[known], 1)
        have = (counts[inverse] > 0) & (g >= 0) & todo
        out[rows[have], cols[have]] = sums[inverse[have]] / counts[inverse[have], None]
        todo &= ~have
    out[rows[todo], cols[todo]] = mean
    return out


def paint(generator, mesh, photos: np.ndarray, masks: np.ndarray, c2w: np.ndarray, fov_x: float,
          lighting: str | None = "reference", res: int = TEXTURE_RES, spp: int = 32,
          refinement: Refinement | None = None, seed: int = 0, passes: int = SHADING_PASSES) -> tuple[dict, dict]:
    """Every part's texture {part index: (res, res, 3) linear albedo} of a fitted ``mesh`` (world
    frame, the generator's UVs) from linear photos (n, H, W, 3) with their masks and cameras, and
    per part the share of its texels some view saw. Under the ``reference`` lighting the photos
    are divided by its shading (``passes`` projections, see :data:`SHADING_PASSES`) and the
    textures then refined (``refinement``; None: not); under an unknown one (None) the texture
    keeps the photos' colours, their light and shade with them."""
    from ipm.render.textured import render_painted

    if mesh.uv is None:
        raise UserError("the mesh has no texture coordinates")
    n, h, w = photos.shape[:3]
    if masks.shape != (n, h, w):
        raise UserError(f"masks {masks.shape} do not match the photos {photos.shape[:3]}")
    if passes < 1:
        raise UserError(f"the texture stage needs at least one projection, not {passes}")
    if lighting == "reference":
        shading = render_painted(mesh.vertices, mesh.faces, mesh.labels, mesh.uv, {}, c2w, fov_x, w, h, spp).mean(-1)
    elif lighting is None:
        shading, passes = np.ones((n, h, w)), 1
    else:
        raise UserError(f"unknown lighting {lighting!r} (known: reference, or none)")
    scene = mesh_scene(mesh.vertices, mesh.faces)
    parts = {int(part): sightings(mesh, int(part), masks, c2w, fov_x, res, scene) for part in np.unique(mesh.labels)}
    groups = {part: generator.texture_symmetry(part, res) for part in parts}
    for k in range(passes):
        if k:
            shading = painted_shading(mesh, textures, c2w, fov_x, w, h, spp, shading)
        textures, seen_share = {}, {}
        for part, (tx, seen_by) in parts.items():
            texture, seen = project(tx, seen_by, photos, shading, res)
            textures[part] = pad(np.clip(fill(texture, seen, (tx.rows, tx.cols), groups[part]), 0.0, 1.0),
                                 (tx.rows, tx.cols))
            seen_share[part] = float((seen[tx.rows, tx.cols] > 0).mean()) if len(tx.rows) else 0.0
    if lighting == "reference" and refinement is not None and refinement.stages:
        textures = refine(mesh, textures, photos, masks, c2w, fov_x, refinement, seed)
    return textures, seen_share


def painted_shading(mesh, textures: dict, c2w: np.ndarray, fov_x: float, width: int, height: int, spp: int,
                    fallback: np.ndarray) -> np.ndarray:
    """The shading (n, height, width, 3) the mesh painted with ``textures`` gets under the reference
    lighting: its render over the albedo each pixel sees (:func:`ipm.render.textured.render_albedo`),
    ``fallback`` ((n, H, W) or (n, H, W, 3)) where that albedo is too dark to divide by."""
    from ipm.render.textured import render_albedo, render_painted

    args = (mesh.vertices, mesh.faces, mesh.labels, mesh.uv, textures, c2w, fov_x, width, height)
    radiance, albedo = render_painted(*args, spp), render_albedo(*args, spp)
    fallback = np.broadcast_to(fallback[..., None] if fallback.ndim == 3 else fallback, radiance.shape)
    dark = albedo < 0.02
    return np.where(dark, fallback, radiance / np.where(dark, 1.0, albedo))


def _enlarge(small: int, large: int):
    """Bilinear enlargement of a (small, small, 3) image to (large, large, 3) (texel centres,
    edges clamped) as four gathers: per corner the flat indices into the small image and the
    weights, each over the large image's flat (large * large * 3) values."""
    x = (np.arange(large) + 0.5) * small / large - 0.5
    lo = np.clip(np.floor(x).astype(np.int64), 0, small - 1)
    hi = np.minimum(lo + 1, small - 1)
    w = np.clip(x - lo, 0.0, 1.0)
    out = []
    for rows, wr in ((lo, 1 - w), (hi, w)):
        for cols, wc in ((lo, 1 - w), (hi, w)):
            index = (rows[:, None] * small + cols[None, :])[..., None] * 3 + np.arange(3)
            weight = np.broadcast_to((wr[:, None] * wc[None, :])[..., None], index.shape)
            out.append((index.ravel().astype(np.uint32), weight.ravel().astype(np.float32)))
    return out


def refine(mesh, textures: dict, photos: np.ndarray, masks: np.ndarray, c2w: np.ndarray, fov_x: float,
           refinement: Refinement = Refinement(), seed: int = 0) -> dict:
    """``textures`` (part -> (res, res, 3) linear albedo) refined to the input views under the
    reference lighting: per stage a correction at the stage's resolution, bilinearly enlarged and
    added to the textures (clipped to [0, 1]), is fitted by Adam to the masked (rim-eroded) squared
    error of Mitsuba's differentiable renders (prb) against the photos, one view a step, then
    folded in; coarse stages first, so what one view says spreads as smooth corrections before
    texel-sized ones."""
    import drjit as dr
    import mitsuba as mi

    from ipm.render.textured import lit_scene, painted_shapes

    n, h, w = photos.shape[:3]
    scene = lit_scene(painted_shapes(mesh.vertices, mesh.faces, mesh.labels, mesh.uv, textures), c2w, fov_x, w, h,
                      "prb")
    params = mi.traverse(scene)
    keys = {k: f"part_{k}.bsdf.reflectance.data" for k in textures}
    shape = {k: tuple(textures[k].shape) for k in textures}
    held = []  # every numpy buffer behind a Dr.Jit array, kept alive: the array may share its memory

    def kept(kind, array, dtype=np.float32):
        held.append(np.ascontiguousarray(array, dtype))
        return kind(held[-1])

    base = {k: kept(mi.Float, textures[k][::-1].ravel()) for k in textures}
    eroded = [np.repeat(_eroded(m)[..., None], 3, -1) for m in masks]
    weights, weight_sums = [kept(mi.TensorXf, e) for e in eroded], [float(e.sum()) for e in eroded]
    targets = [kept(mi.TensorXf, p) for p in photos]
    step = 0
    for res, steps in refinement.stages:
        by_size = {size: [(kept(mi.UInt32, i, np.uint32), kept(mi.Float, wt)) for i, wt in _enlarge(res, size)]
                   for size in {shape[k][0] for k in textures}}
        maps = {k: by_size[shape[k][0]] for k in textures}
        opt = mi.ad.Adam(lr=refinement.lr)
        for k in textures:
            opt[keys[k]] = dr.zeros(mi.Float, res * res * 3)

        def full(k):
            delta = opt[keys[k]]
            return dr.clip(base[k] + sum(dr.gather(mi.Float, delta, i) * wt for i, wt in maps[k]), 0.0, 1.0)

        for _ in range(steps):
            view = step % n
            for k in textures:
                params[keys[k]] = mi.TensorXf(full(k), shape[k])
            params.update()
            image = mi.render(scene, params, sensor=view, spp=refinement.spp, seed=seed * 100003 + step)
            if weight_sums[view] > 0:
                loss = dr.sum(dr.square(image - targets[view]) * weights[view])
                dr.backward(loss / weight_sums[view])
                opt.step()
            step += 1
        base = {k: dr.detach(full(k)) for k in textures}
        dr.eval(base)
    return {k: np.array(base[k], np.float64).reshape(shape[k])[::-1].copy() for k in textures}


def read_textures(folder, part_names: tuple[str, ...]) -> dict[int, np.ndarray]:
    """The part textures of a result's textures/ folder: {part index: sRGB image (res, res, 3)
    uint8} for each part with a PART.png; ``UserError`` where the folder is missing or holds none."""
    from pathlib import Path

    from PIL import Image

    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"textures folder not found: {folder}")
    out = {}
    for k, name in enumerate(part_names):
        path = folder / f"{name}.png"
        if path.is_file():
            try:
                with Image.open(path) as im:
                    out[k] = np.asarray(im.convert("RGB"))
            except OSError as exc:
                raise UserError(f"cannot read texture {path}: {exc}") from None
    if not out:
        raise UserError(f"{folder} holds no part texture ({', '.join(f'{n}.png' for n in part_names)})")
    return out


def dress(generator, mesh, views) -> tuple[dict | None, dict, float]:
    """The texture stage on a fitted ``mesh`` (world frame) from its input ``views``
    (``ipm.io.views.Views``): its textures (None where the views have no colour images or their
    camera is an estimate), params.json's ``texture`` record (the lighting and each part's seen
    share; why not where a colour image cannot be read, the fit standing unpainted; empty where
    there was nothing to paint from) and the stage's seconds."""
    import time

    from ipm.io.views import load_photos

    t0 = time.perf_counter()
    if views is None or not views.posed or views.camera is not None or views.masks is None:
        return None, {}, 0.0
    try:
        photos = load_photos(views)
        if photos is None:
            return None, {}, 0.0
        textures, seen = paint(generator, mesh, photos, views.masks, views.c2w, views.fov_x, views.lighting,
                               refinement=REFINEMENT)
    except UserError as exc:
        return None, {"texture": {"skipped": str(exc)}}, round(time.perf_counter() - t0, 2)
    record = {"lighting": views.lighting, "seen": {mesh.part_names[k]: round(s, 4) for k, s in seen.items()}}
    return textures, {"texture": record}, round(time.perf_counter() - t0, 2)
