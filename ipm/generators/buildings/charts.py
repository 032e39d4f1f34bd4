"""Texture charts of the buildings' solids: every planar face of a box or a roof a rectangle (a
roof's end a pentagon in one) sized by the face at a topology's reference parameters, packed per
part into its unit square (``ipm.uv.pack_parts``). A chart's shape does not follow the parameters, so a
part's texture stays on its faces when they move."""
from __future__ import annotations

import numpy as np

from ipm.generators.buildings.solids import BITS, BOX_FACES, ROOF_FACES
from ipm.uv import pack_parts

MIN_SIDE = 0.05
"""The least side of a face's chart (object units): a face that is flat where the chart is drawn
still gets texels for where the parameters open it."""
END = np.array([[0.0, 0.0], [0.2, 0.6], [0.5, 1.0], [0.8, 0.6], [1.0, 0.0]])
"""A roof end's pentagon (eave, knee, ridge, knee, eave) across its span and up its rise: every
triangle of an end keeps an area whatever the roof kind."""


def _box_template():
    """Each box triangle's face (6 faces, two triangles each) and its corners in the face's unit
    square: the corner's bits on the face's two free axes."""
    axes = []
    for q in range(6):
        corners = BOX_FACES[2 * q:2 * q + 2].ravel()
        fixed = np.all(BITS[corners] == BITS[corners[0]], 0)
        axes.append(np.flatnonzero(~fixed))
    axes = np.array(axes)  # (6, 2)
    face = np.repeat(np.arange(6), 2)
    unit = np.stack([BITS[BOX_FACES[t]][:, axes[face[t]]] for t in range(12)]).astype(float)
    return face, unit, axes


def _roof_template():
    """Each roof triangle's face (bottom, four slopes, two ends) and its corners in the face's unit
    square, in ``ROOF_FACES``' order."""
    face = np.array([0, 0, 1, 2, 3, 4, 1, 2, 3, 4, 5, 5, 5, 6, 6, 6])
    unit = np.zeros((16, 3, 2))
    unit[0] = [[0, 0], [1, 1], [1, 0]]  # (0, 9, 4): across the span, along the length
    unit[1] = [[0, 0], [0, 1], [1, 1]]  # (0, 5, 9)
    unit[2:6] = [[0, 0], [1, 0], [1, 1]]  # (k, k+1, k+6): down the slope's section, along the length
    unit[6:10] = [[0, 0], [1, 1], [0, 1]]  # (k, k+6, k+5)
    unit[10:13] = END[ROOF_FACES[10:13]]
    unit[13:16] = END[ROOF_FACES[13:16] - 5]
    return face, unit


BOX_FACE, BOX_UNIT, BOX_AXES = _box_template()
ROOF_FACE, ROOF_UNIT = _roof_template()


def _box_sizes(corners: np.ndarray) -> np.ndarray:
    """Each face's chart size (n, 6, 2) of boxes (n, 8, 3): its extents on its two free axes."""
    size = np.maximum(corners[:, 7] - corners[:, 0], MIN_SIDE)
    return size[:, BOX_AXES]


def _roof_sizes(v: np.ndarray) -> np.ndarray:
    """Each face's chart size (n, 7, 2) of roofs (n, 10, 3): the bottom's span and length, each
    slope's section and length, each end's span and rise."""
    length = np.maximum(np.linalg.norm(v[:, 5] - v[:, 0], axis=-1), MIN_SIDE)
    span = np.maximum(np.linalg.norm(v[:, 4] - v[:, 0], axis=-1), MIN_SIDE)
    section = np.maximum(np.linalg.norm(v[:, 1:5] - v[:, :4], axis=-1), MIN_SIDE)  # (n, 4)
    eave = (v[:, 4] - v[:, 0]) / span[:, None]
    off = v[:, 1:4] - v[:, :1]
    off -= np.einsum("nkj,nj->nk", off, eave)[..., None] * eave[:, None]
    rise = np.maximum(np.linalg.norm(off, axis=-1).max(1), 0.25 * span)  # the end's height in its plane
    sizes = np.empty((len(v), 7, 2))
    sizes[:, 0] = np.stack([span, length], -1)
    sizes[:, 1:5] = np.stack([section, np.broadcast_to(length[:, None], section.shape)], -1)
    sizes[:, 5:] = np.stack([span, rise], -1)[:, None]
    return sizes


TEMPLATE_CHARTS = {"box": (BOX_FACES, BOX_FACE, BOX_UNIT, _box_sizes),
                   "roof": (ROOF_FACES, ROOF_FACE, ROOF_UNIT, _roof_sizes)}


def _face_charts(kind: str, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solids (n, k, 3) of ``kind``: per-corner chart coordinates (n, T, 3, 2) and each face's chart
    size (n, faces, 2). A face is drawn as it lies in its plane at ``v``; a face with a triangle
    that has no area there (a roof kind's collapsed band) takes the template's shape at its
    measured size instead, so every triangle keeps texels."""
    tris, face, unit, measure = TEMPLATE_CHARTS[kind]
    fallback = measure(v)  # (n, faces, 2)
    n, n_faces = len(v), fallback.shape[1]
    local = unit[None] * fallback[:, face][:, :, None, :]
    sizes = fallback.copy()
    p = v[:, tris]  # (n, T, 3, 3)
    for f in range(n_faces):
        pf = p[:, face == f]  # (n, t, 3, 3)
        normal = np.cross(pf[:, :, 1] - pf[:, :, 0], pf[:, :, 2] - pf[:, :, 0]).sum(1)
        normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
        e1 = np.cross([0.0, 1.0, 0.0], normal)  # level in the face: a facade's courses run along u
        level = np.linalg.norm(e1, axis=-1, keepdims=True) > 1e-3
        e1 = np.where(level, e1 / np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-12), [1.0, 0.0, 0.0])
        e2 = np.cross(normal, e1)
        flat = np.stack([np.einsum("ntcj,nj->ntc", pf, e1), np.einsum("ntcj,nj->ntc", pf, e2)], -1)
        flat -= flat.reshape(n, -1, 2).min(1)[:, None, None]
        extent = flat.reshape(n, -1, 2).max(1)
        d1, d2 = flat[:, :, 1] - flat[:, :, 0], flat[:, :, 2] - flat[:, :, 0]
        area = 0.5 * np.abs(d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0])
        drawn = (area > 0.01 * MIN_SIDE ** 2).all(1) & (extent >= MIN_SIDE).all(1)
        local[drawn[:, None] & (face == f)[None]] = flat[drawn].reshape(-1, 3, 2)
        sizes[drawn, f] = extent[drawn]
    return local, sizes


def charts(kinds: list[tuple[str, int, int]], positions: np.ndarray, parts: np.ndarray,
           present: np.ndarray) -> np.ndarray:
    """Per-corner UVs (F, 3, 2) of the present solids' triangles, in the layout's order: ``kinds``
    (kind, solids, vertices a solid) as laid out, every solid's positions at the reference
    parameters, each solid's part and whether the building has it. Each part's faces are packed
    into its own unit square. Every solid of a kind is charted in one call (a building's layout
    has about thirty groups of solids and two kinds)."""
    groups, offset, solid, of_kind = [], 0, 0, {}  # of_kind: solids of each kind so far
    for kind, n, k in kinds:
        groups.append((kind, n, positions[offset:offset + n * k].reshape(n, k, 3), solid, of_kind.get(kind, 0)))
        offset += n * k
        solid += n
        of_kind[kind] = of_kind.get(kind, 0) + n
    charted = {}  # kind -> (local (n, T, 3, 2), sizes (n, faces, 2)) of all its solids, in layout order
    for kind in of_kind:
        charted[kind] = _face_charts(kind, np.concatenate([v for g, _, v, _, _ in groups if g == kind]))
    units, sizes, tri_face, face_part, face_keep = [], [], [], [], []
    faces_before = 0
    for kind, n, _, solid, first in groups:  # first: the group's index among its kind's solids
        face = TEMPLATE_CHARTS[kind][1]
        local, size = (a[first:first + n] for a in charted[kind])
        n_faces = size.shape[1]
        units.append(local.reshape(-1, 3, 2))
        tri_face.append((faces_before + n_faces * np.arange(n)[:, None] + face[None]).ravel())
        sizes.append(size.reshape(-1, 2))
        face_part.append(np.repeat(parts[solid:solid + n], n_faces))
        face_keep.append(np.repeat(present[solid:solid + n], n_faces))
        faces_before += n * n_faces
    units, tri_face, sizes = np.concatenate(units), np.concatenate(tri_face), np.concatenate(sizes)
    face_part, face_keep = np.concatenate(face_part), np.concatenate(face_keep).astype(bool)
    kept = face_keep[tri_face]
    return pack_parts(units[kept], tri_face[kept], sizes, face_part[tri_face][kept])
