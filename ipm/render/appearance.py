"""The references' appearance: materials a person would recognise, painted on a case's own UVs.

A cup wears a speckled stoneware glaze with a spotted print, two printed bands below its rim and
a star on one side; a building's walls are brick or render over a stone plinth, its pitched roofs
tiled in courses (a flat roof gravel), its windows glass in white frames, its doors planked wood.
Each material is a solid texture (a colour for each surface point and normal, in the world's units
at the suite's 10 m a unit), baked into one bitmap per part through the part's UVs, so the texture
stage's projection and refinement see a texture with the statistics of a real object's: areas of
one colour, straight edges, a motif the input view may or may not show. Spots, brick and tile give
COLMAP's features. Every choice (glazes, the bands, the star's side, brick or render, the roof's
colour) follows the case's ``texture_seed``.
"""
from __future__ import annotations

import numpy as np

from ipm.io.views import linear_from_srgb
from ipm.uv import pad, texels

TEXTURE_SIZE = 512
"""Texels along a side of each part's baked bitmap."""

GLAZES = np.array([(0.93, 0.89, 0.80), (0.95, 0.95, 0.93), (0.16, 0.30, 0.62), (0.55, 0.64, 0.50),
                   (0.74, 0.42, 0.28), (0.26, 0.26, 0.28), (0.85, 0.68, 0.25)])
"""Glaze colours (sRGB): cream, white, cobalt, sage, terracotta, charcoal, mustard."""
RENDERS = np.array([(0.93, 0.91, 0.86), (0.92, 0.86, 0.68), (0.80, 0.80, 0.78), (0.90, 0.74, 0.66)])
"""Rendered walls' colours (sRGB): white, ochre, grey, salmon."""
BRICKS = np.array([(0.58, 0.27, 0.19), (0.66, 0.42, 0.30), (0.48, 0.30, 0.24)])
"""Brick colours (sRGB): red, buff-red, brown."""
TILES = np.array([(0.62, 0.29, 0.19), (0.30, 0.32, 0.36), (0.42, 0.26, 0.19)])
"""Roof tile colours (sRGB): terracotta, slate, brown."""


def lattice_noise(points: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """A value in [0, 1) for each point's cell of a cubic lattice of side ``cell``: one hash a cell."""
    ijk = np.floor(np.asarray(points) / cell).astype(np.int64)
    h = (ijk[:, 0] * 73856093) ^ (ijk[:, 1] * 19349663) ^ (ijk[:, 2] * 83492791) ^ (seed * 2654435761)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFFFF) / float(1 << 24)


def smooth_noise(points: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """Value noise in [0, 1): :func:`lattice_noise` at a cell's corners, interpolated (smoothstep)."""
    x = np.asarray(points, np.float64) / cell
    base, frac = np.floor(x), x - np.floor(x)
    w = frac * frac * (3.0 - 2.0 * frac)
    out = np.zeros(len(x))
    for corner in np.ndindex(2, 2, 2):
        c = np.asarray(corner)
        weight = np.prod(np.where(c, w, 1.0 - w), axis=1)
        out += weight * lattice_noise(base + c + 0.5, 1.0, seed)
    return out


def bake(vertices, faces, corner_uv, colour, size: int = TEXTURE_SIZE) -> np.ndarray:
    """A (size, size, 3) bitmap (glTF's rows: the first at v = 1) of a part whose texel centres
    take ``colour(points (n, 3), normals (n, 3))`` at the surface point each maps to (``ipm.uv.texels``);
    texels no triangle covers take their nearest covered texel's colour (no dark seams under
    filtering). UVs past 1 (a revolved part's seam) wrap, as the renderer's bitmap does."""
    f, uv = np.asarray(faces), np.asarray(corner_uv, np.float64)
    uv = uv - np.floor(uv.min(1, keepdims=True))  # each triangle's UVs from [0, 1)
    over = np.flatnonzero(uv.max((1, 2)) > 1.0)  # and a copy one to the left where they pass 1
    uv = np.concatenate([uv, uv[over] - (uv[over].max(1, keepdims=True) > 1.0)])
    found = texels(vertices, np.concatenate([f, f[over]]), uv, size)
    out = np.full((size, size, 3), 0.5)
    if len(found.rows) == 0:
        return out
    out[found.rows, found.cols] = colour(found.points, found.normals)
    return pad(out, (found.rows, found.cols))


def cup_design(seed: int) -> dict:
    """A cup's glaze, print and motif for ``seed``: colours (linear) ``glaze``, ``band`` (the
    bands' and the star's) and ``dots``, the bands' ``top`` and ``widths`` (in body heights), the
    star's azimuth ``star_at`` (radians), height ``star_h`` and radius ``star_r``."""
    rng = np.random.default_rng(seed)
    glaze_i = int(rng.integers(len(GLAZES)))
    band_i = (glaze_i + int(rng.integers(1, len(GLAZES)))) % len(GLAZES)
    glaze, band = linear_from_srgb(GLAZES[glaze_i]), linear_from_srgb(GLAZES[band_i])
    if np.abs(glaze - band).sum() < 0.6:  # two near glazes: a dark print
        band = linear_from_srgb(np.array((0.12, 0.16, 0.35)))
    top, widths = rng.uniform(0.72, 0.8), rng.uniform(0.025, 0.06, 2)
    star_at, star_h, star_r = rng.uniform(-np.pi, np.pi), rng.uniform(0.35, 0.5), rng.uniform(0.12, 0.18)
    dots = [linear_from_srgb(GLAZES[(glaze_i + int(j)) % len(GLAZES)]) for j in rng.choice(np.arange(1, len(GLAZES)), 2, False)]
    return {"glaze": glaze, "band": band, "dots": dots, "top": top, "widths": widths, "star_at": star_at,
            "star_h": star_h, "star_r": star_r}


def cup_material(body, seed: int):
    """The colour function of a cup (:func:`cup_design`'s), framed on its body's points (n, 3): the
    axis through the body's middle, heights over the body's."""
    body = np.asarray(body, np.float64)
    lo, hi = body.min(0), body.max(0)
    centre, height = 0.5 * (lo + hi), max(hi[1] - lo[1], 1e-6)
    d = cup_design(seed)
    glaze, band, dots, top, widths = d["glaze"], d["band"], d["dots"], d["top"], d["widths"]
    star_at, star_h, star_r = d["star_at"], d["star_h"], d["star_r"]

    def colour(p, n):
        h = (p[:, 1] - lo[1]) / height
        radial = p[:, [0, 2]] - centre[[0, 2]]
        r = np.maximum(np.linalg.norm(radial, axis=1), 1e-9)
        outside = (n[:, [0, 2]] * radial).sum(1) / r > 0.2
        angle = (np.arctan2(radial[:, 1], radial[:, 0]) - star_at + np.pi) % (2 * np.pi) - np.pi
        dx = angle * r / height  # along the body's surface round the axis, in body heights
        out = np.tile(glaze, (len(p), 1)) * (0.86 + 0.28 * smooth_noise(p, 0.06 * height, seed))[:, None]
        level = np.abs(n[:, 1]) > 0.7  # a foot, a bottom: spots on the plane, not round the axis
        sx = np.where(level, (p[:, 0] - centre[0]) / height, dx)
        sy = np.where(level, (p[:, 2] - centre[2]) / height, h)
        for k, dot in enumerate(dots):  # the spotted glaze, inside and out, a colour at a time
            out[_spots(sx, sy, 0.09, seed + 10 + k)] = dot
        printed = (h <= top) & (h > top - widths[0])
        printed |= (h <= top - 1.6 * widths[0]) & (h > top - 1.6 * widths[0] - widths[1])
        rho, theta = np.hypot(dx, h - star_h), np.arctan2(h - star_h, dx) - np.pi / 2
        printed |= rho < star_r * (0.42 + 0.58 * ((np.cos(5 * theta) + 1) / 2) ** 3)
        out[printed & outside] = band
        for cell, share, dark in ((height / 160, 0.08, 0.45), (height / 45, 0.05, 0.3)):  # iron spots
            spot = lattice_noise(p, cell, seed + 1) < share
            out[spot] *= dark + 0.3 * lattice_noise(p[spot], cell, seed + 2)[:, None]
        return out

    return colour


def _spots(x, y, cell: float, seed: int) -> np.ndarray:
    """Whether surface coordinates (x, y) lie in a spot of a jittered grid of ``cell``: each cell
    has one spot, of radius 0.12-0.3 cells, with probability 0.7."""
    i, j = np.floor(x / cell), np.floor(y / cell)
    key = np.stack([i, j, np.zeros_like(i)], 1)
    u = [lattice_noise(key, 1.0, seed + m) for m in range(4)]
    cx, cy = (i + 0.3 + 0.4 * u[0]) * cell, (j + 0.3 + 0.4 * u[1]) * cell
    return (u[3] < 0.7) & (np.hypot(x - cx, y - cy) < (0.12 + 0.18 * u[2]) * cell)


def building_materials(vertices, seed: int) -> dict:
    """Colour functions of a building's materials by name (``wall``, ``trim``, ``window``, ``roof``,
    ``door``; see the module's text)."""
    rng = np.random.default_rng(seed)
    ground = float(np.min(np.asarray(vertices)[:, 1]))
    brick = bool(rng.random() < 0.5)
    wall = linear_from_srgb(BRICKS[int(rng.integers(len(BRICKS)))] if brick else RENDERS[int(rng.integers(len(RENDERS)))])
    tile = linear_from_srgb(TILES[int(rng.integers(len(TILES)))])

    def along(p, n):
        """Each point's horizontal coordinate along its face (the eave's direction)."""
        t = np.stack([-n[:, 2], np.zeros(len(n)), n[:, 0]], 1)
        flat = np.linalg.norm(t, axis=1) < 0.2
        t[flat] = (1.0, 0.0, 0.0)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        return (p * t).sum(1)

    def courses(p, n, height, length):
        """Each point's course (row) index and its block's index along the course (half-bond)."""
        y = (p[:, 1] - ground) / height
        row = np.floor(y)
        x = along(p, n) / length + 0.5 * (row % 2)
        col = np.floor(x)
        return row, col, y - row, x - col

    def walls(p, n):
        if brick:  # 0.25 x 0.075 m, 1 cm mortar
            row, col, fy, fx = courses(p, n, 0.0075, 0.025)
            jitter = lattice_noise(np.stack([row, col, row * 0], 1), 1.0, seed + 2)
            out = wall[None] * (0.8 + 0.4 * jitter)[:, None]
            out[(fy < 0.13) | (fx < 0.04)] = linear_from_srgb(np.array((0.72, 0.70, 0.66)))
        else:
            out = wall[None] * (0.93 + 0.14 * lattice_noise(p, 0.04, seed + 2))[:, None]
            out *= (0.96 + 0.08 * lattice_noise(p, 0.004, seed + 3))[:, None]
        plinth = p[:, 1] - ground < 0.05
        out[plinth] = linear_from_srgb(np.array((0.55, 0.55, 0.53))) * (0.9 + 0.2 * lattice_noise(p[plinth], 0.01, seed + 4))[:, None]
        return out

    def roof(p, n):
        row, col, fy, fx = courses(p, n, 0.03, 0.025)
        jitter = lattice_noise(np.stack([row, col, row * 0], 1), 1.0, seed + 6)
        out = tile[None] * (0.85 + 0.3 * jitter)[:, None]
        out[fy < 0.15] *= 0.45  # the shadowed lower edge of the course above
        out[fx < 0.06] *= 0.7
        flat = n[:, 1] > 0.995  # a flat roof (and a parapet's top): gravel
        out[flat] = linear_from_srgb(np.array((0.45, 0.44, 0.42)))[None] * (0.7 + 0.6 * lattice_noise(p[flat], 0.004, seed + 5))[:, None]
        upright = n[:, 1] < 0.2  # a parapet's sides: the walls' masonry
        out[upright] = walls(p[upright], n[upright])
        return out

    def window(p, n):
        return linear_from_srgb(np.array((0.10, 0.13, 0.17)))[None] * (0.8 + 0.4 * lattice_noise(p, 0.03, seed + 7))[:, None]

    def trim(p, n):
        return np.tile(linear_from_srgb(np.array((0.88, 0.88, 0.86))), (len(p), 1))

    def door(p, n):
        planks = np.floor(along(p, n) / 0.012)
        return linear_from_srgb(np.array((0.36, 0.21, 0.11)))[None] * (0.8 + 0.4 * lattice_noise(
            np.stack([planks, planks * 0, planks * 0], 1), 1.0, seed + 8))[:, None]

    return {"wall": walls, "trim": trim, "window": window, "roof": roof, "door": door}


BUILDING_PARTS = {"walls": "wall", "windows": "window", "frames": "trim", "roof": "roof", "door": "door",
                  "balconies": "trim"}
"""The material of each part of the buildings generator; a recipe's parts take their semantic class's."""


def reference_textures(kind: str, vertices, faces, labels, corner_uv, seed: int, part_materials=None,
                       size: int = TEXTURE_SIZE) -> dict:
    """One baked bitmap per part label (``bake``) of a cup (``kind`` "cup") or a building
    ("building", ``part_materials`` naming each label's material of :func:`building_materials`)."""
    faces, labels = np.asarray(faces), np.asarray(labels)
    if kind == "cup":
        body = faces[labels == 0] if np.any(labels == 0) else faces  # label 0: a dish's body
        colour = cup_material(np.asarray(vertices)[body.ravel()], seed)
        materials = {int(k): colour for k in np.unique(labels)}
    else:
        found = building_materials(vertices, seed)
        materials = {int(k): found[part_materials[int(k)]] for k in np.unique(labels)}
    return {k: bake(vertices, faces[labels == k], np.asarray(corner_uv)[labels == k], colour, size)
            for k, colour in materials.items()}

