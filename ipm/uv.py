"""Texture coordinates: one UV per triangle corner, charts of swept surfaces, their packing, and
the two measures of a layout (overlap inside a part, texel stretch) that ``docs/design``,
"Outputs" asks of every generator.

A corner's UV (shape (F, 3, 2)) lets a seam split a vertex without splitting the mesh: the
positions stay one watertight solid, and a file's writer welds the corners that share a vertex
and a UV (``ipm.io.mesh.weld``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def corners_from_vertices(faces: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Per-corner UVs (F, 3, 2) from per-vertex ones (V, 2), u unwrapped across the seam of a
    revolved part (a triangle whose u spans more than a half takes its small u past 1)."""
    corner = np.asarray(uv, np.float64)[np.asarray(faces)].copy()
    u = corner[..., 0]
    wrap = (u.max(1) - u.min(1)) > 0.5
    u[wrap] = np.where(u[wrap] < 0.5, u[wrap] + 1.0, u[wrap])
    return corner


def sweep_uv(faces: np.ndarray, n_rows: int, n_ring: int, offset: int, row_v: np.ndarray,
             strip: tuple[float, float, float, float], caps: tuple[tuple[float, float, float], ...]) -> np.ndarray:
    """Per-corner UVs of a closed sweep (``ipm.generators.geometry.closed_sweep_faces``: pole A, rows
    of ``n_ring`` vertices, pole B, from ``offset``): the rows unrolled into ``strip`` (u0, v0, u1, v1),
    u by the ring's angle (the seam's column at u1), v by ``row_v`` (n_rows,) in [0, 1]; each pole's
    fan flattened into its cap's disc (centre u, centre v, radius), the ring at the disc's edge."""
    faces = np.asarray(faces) - offset
    u0, v0, u1, v1 = strip
    pole_a, pole_b = 0, 1 + n_rows * n_ring
    row, col = np.divmod(np.clip(faces - 1, 0, None), n_ring)
    seam = (col.max(1, keepdims=True) == n_ring - 1) & (col == 0)
    frac = (col + n_ring * seam) / n_ring
    out = np.stack([u0 + (u1 - u0) * frac, v0 + (v1 - v0) * np.asarray(row_v)[np.minimum(row, n_rows - 1)]], -1)
    for pole, (cu, cv, r) in zip((pole_a, pole_b), caps):
        fan = (faces == pole).any(1)
        theta = 2 * np.pi * col[fan] / n_ring
        disc = np.stack([cu + r * np.cos(theta), cv + r * np.sin(theta)], -1)
        disc[faces[fan] == pole] = (cu, cv)
        out[fan] = disc
    return out


def texel_hits(corner_uv: np.ndarray, res: int, edges: bool = True, chunk: int = 1 << 22):
    """For the triangles with an area in UV (F, 3, 2), the texel centres of a ``res`` square over
    [0, 1]^2 inside each (``edges``: on its edges too), all at once: the triangle's index, the
    texel's column and row (row 0 at v = 0) and its barycentric coordinates (n, 3), ordered by
    triangle. Candidates (each triangle's texel box) are tested ``chunk`` at a time."""
    tri = np.asarray(corner_uv, np.float64) * res - 0.5  # texel centres at integers
    lo = np.clip(np.ceil(tri.min(1)), 0, res - 1).astype(np.int64)
    hi = np.clip(np.floor(tri.max(1)), 0, res - 1).astype(np.int64)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    width, height = np.maximum(hi - lo + 1, 0).T
    count = np.where(np.abs(det) > 1e-12, width * height, 0)
    eps = -1e-9 if edges else 1e-9
    found = []
    ends = np.cumsum(count)
    starts = ends - count  # each triangle's first candidate
    first = 0
    while first < len(count):  # triangles [first, last) hold at most ``chunk`` candidates (or one triangle)
        last = max(first + 1, int(np.searchsorted(ends, starts[first] + chunk, side="right")))
        k = np.repeat(np.arange(first, last), count[first:last])
        local = np.arange(starts[first], ends[last - 1]) - starts[k]  # the candidate's place in its box
        xs, ys = lo[k, 0] + local % width[k], lo[k, 1] + local // width[k]
        px, py = xs - a[k, 0], ys - a[k, 1]
        s = (px * (c[k, 1] - a[k, 1]) - py * (c[k, 0] - a[k, 0])) / det[k]
        t = (py * (b[k, 0] - a[k, 0]) - px * (b[k, 1] - a[k, 1])) / det[k]
        inside = (s > eps) & (t > eps) & (s + t < 1 - eps)
        s, t = s[inside], t[inside]
        found.append((k[inside], xs[inside], ys[inside], np.stack([1 - s - t, s, t], -1)))
        first = last
    if not found:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    return tuple(np.concatenate(parts) for parts in zip(*found))


@dataclass
class Texels:
    """The texels one part's charts cover: their rows and columns, and the surface point, facet
    normal and triangle of each."""

    rows: np.ndarray
    cols: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray


def texels(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, res: int) -> Texels:
    """The texel centres of a ``res`` square texture that the triangles' UVs (F, 3, 2) cover (u along
    the columns, v along the rows from the bottom, as glTF's and Mitsuba's bitmaps are read)."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces)
    owner = np.full((res, res), -1)
    weights = np.zeros((res, res, 3))
    hit, cols, rows, bary = texel_hits(uv, res)
    np.maximum.at(owner, (rows, cols), hit)  # a texel two triangles cover: the later triangle's
    last = owner[rows, cols] == hit
    weights[rows[last], cols[last]] = bary[last]
    v_idx, u_idx = np.nonzero(owner >= 0)
    k = owner[v_idx, u_idx]
    corners = vertices[faces[k]]  # (N, 3, 3)
    points = np.einsum("nc,ncj->nj", weights[v_idx, u_idx], corners)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    return Texels(res - 1 - v_idx, u_idx, points, normal, k)


def pad(texture: np.ndarray, covered: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``texture`` with every texel outside the charts (not among ``covered`` (rows, cols)) set to
    its nearest covered texel's colour, so that filtering at a chart's edge never reads the empty
    gutter (a band one or two texels high, a goblet's foot, would render dark)."""
    from scipy.ndimage import distance_transform_edt

    outside = np.ones(texture.shape[:2], bool)
    outside[covered] = False
    if outside.all():
        return texture
    rows, cols = distance_transform_edt(outside, return_distances=False, return_indices=True)
    return texture[rows, cols]


def overlap(corner_uv: np.ndarray, res: int = 1024) -> float:
    """Share of the texels (centres of a ``res`` square over [0, 1]^2) inside some triangle that lie
    inside more than one: 0 for a layout without overlaps (a texel on a shared edge counts for
    neither triangle)."""
    _, cols, rows, _ = texel_hits(corner_uv, res, edges=False)
    count = np.zeros((res, res), np.int32)
    np.add.at(count, (rows, cols), 1)
    covered = int((count > 0).sum())
    return float((count > 1).sum() / covered) if covered else 0.0


def stretch(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Texel stretch per triangle and its surface area: how many times farther than a typical texel
    of the part a texel reaches on the surface along its longest direction (the largest singular
    value of the map from UV to surface, Sander et al.'s L-infinity stretch, over the part's
    area-weighted median of the triangles' mean scales: 1 for a similarity at that density, below 1
    where texels are to spare; infinite where a triangle has no UV area)."""
    p = np.asarray(vertices, np.float64)[np.asarray(faces)]
    q = np.asarray(corner_uv, np.float64)
    e = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], -1)  # (F, 3, 2)
    d = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], -1)  # (F, 2, 2)
    area3 = 0.5 * np.linalg.norm(np.cross(e[..., 0], e[..., 1]), axis=1)
    area2 = 0.5 * np.abs(np.linalg.det(d))
    out = np.full(len(p), np.inf)
    ok = area2 > 1e-14 * max(area2.max(initial=0.0), 1e-30)
    if not ok.any():
        return out, area3
    jac = e[ok] @ np.linalg.inv(d[ok])  # (k, 3, 2): UV to surface
    sv = np.linalg.svd(jac, compute_uv=False)
    typical = area_quantile(np.sqrt(area3[ok] / area2[ok]), area3[ok], 0.5)
    out[ok] = sv[:, 0] / max(typical, 1e-30)
    return out, area3


def area_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The ``q`` quantile of ``values`` with each counted by its weight (a triangle by its area)."""
    order = np.argsort(values)
    cum = np.cumsum(np.asarray(weights, np.float64)[order])
    return float(np.asarray(values)[order][min(np.searchsorted(cum, q * cum[-1]), len(cum) - 1)])


def sweep_atlas(strip: tuple[float, float], radii: tuple[float, ...], gutter: float = 4 / 1024):
    """A part's atlas of a swept surface: its strip (width around, length along; surface units) and
    its caps (radii) at one density with ``gutter`` between charts and round the edge, the caps in a
    row below the strip or in a column beside it, whichever lets the charts be larger. Returns the
    strip's box (u0, v0, u1, v1) and the caps' discs (centre u, centre v, radius) in [0, 1]."""
    w, h = strip
    caps = 2 * float(sum(radii))
    big = 2 * max(radii, default=0.0)
    n = len(radii)
    # (extent, gutters) along u and v for caps below, then beside
    layouts = {True: ((max(w, caps), 2 + max(n - 1, 0) * (caps > w)), (h + big, 3)),
               False: ((w + big, 3), (max(h, caps), 2 + max(n - 1, 0) * (caps > h)))}
    scale = {b: min((1 - g * gutter) / e for e, g in axes) for b, axes in layouts.items()}
    below = scale[True] >= scale[False]
    k = scale[below]
    box = (gutter, gutter, gutter + k * w, gutter + k * h)
    discs, at = [], gutter
    for r in radii:
        centre = (at + k * r, box[3] + gutter + k * r) if below else (box[2] + gutter + k * r, at + k * r)
        discs.append((*centre, k * r))
        at += 2 * k * r + gutter
    return box, tuple(discs)


def pack(sizes: np.ndarray, gutter: float = 2 / 1024) -> tuple[np.ndarray, float]:
    """Rectangles ``sizes`` (N, 2) (surface units) placed in the unit square at one scale, ``gutter``
    apart and from the edge, in shelves by height: their lower-left corners (N, 2) and the scale
    (the largest that fits, to a part in a thousand)."""
    sizes = np.asarray(sizes, np.float64)
    order = np.argsort(-sizes[:, 1], kind="stable")
    w, h = sizes[order, 0], sizes[order, 1]

    def shelves(k):
        """Corners at scale ``k`` (sorted order) and the height used, or None where a rectangle is
        wider than the square."""
        room = 1 - 2 * gutter
        if k * w.max(initial=0.0) > room:
            return None
        step = np.cumsum(k * w + gutter)
        corners, i, top = np.zeros((len(w), 2)), 0, gutter
        while i < len(w):
            base = step[i - 1] if i else 0.0
            j = max(int(np.searchsorted(step - base, room + gutter, side="right")), i + 1)
            corners[i:j, 0] = gutter + (step[i:j] - base) - (k * w[i:j] + gutter)
            corners[i:j, 1] = top
            top += k * h[i] + gutter
            i = j
        return corners, top

    lo, hi = 0.0, 1.0 / max(np.sqrt((sizes.prod(1)).sum()), 1e-12)
    while (fit := shelves(hi)) is not None and fit[1] <= 1:
        lo, hi = hi, 2 * hi
    for _ in range(40):
        if hi - lo <= 1e-3 * hi:
            break
        mid = 0.5 * (lo + hi)
        fit = shelves(mid)
        lo, hi = (mid, hi) if fit is not None and fit[1] <= 1 else (lo, mid)
    corners = np.empty_like(sizes)
    corners[order] = shelves(lo)[0]
    return corners, lo


def pack_parts(local: np.ndarray, chart: np.ndarray, sizes: np.ndarray, labels: np.ndarray,
               gutter: float = 2 / 1024) -> np.ndarray:
    """Per-corner UVs (F, 3, 2), each part's charts packed by :func:`pack` into its own unit square:
    each triangle's corners ``local`` (F, 3, 2) in its chart's own frame (surface units, within
    [0, size]), ``chart`` (F,) its chart among ``sizes`` (C, 2), ``labels`` (F,) its part (a chart
    no triangle uses takes no room)."""
    local = np.asarray(local)
    uv = np.zeros_like(local, dtype=np.float64)
    for part in np.unique(labels):
        sel = labels == part
        used, inverse = np.unique(chart[sel], return_inverse=True)
        corner, scale = pack(sizes[used], gutter)
        uv[sel] = corner[inverse][:, None, :] + scale * local[sel]
    return uv
