"""Geometry of the trees generator: its stems, the turns and shapes of W-P's rules, meshes, the graph.

``ipm.generators.trees`` grows a tree's stems, one :class:`Stems` per level, with the vector
helpers, W-P's crown shapes (:func:`shape_ratio`) and stem curvature (:func:`curve_per_segment`)
here; this module turns them into mesh parts and into the tree's skeleton (:class:`BranchGraph`).
Stems are closed tubes (rings along the polyline, flat end caps, outward winding); leaves are
closed, very thin lenses (the leaf outline plus one apex on each side), so each leaf shows
outward-facing triangles to both sides, as one-sided Mitsuba area emitters need, and the whole
tree stays a union of closed parts (volumetric metrics).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LEAF_RIMS = (
    np.array([[0.0, 0.0], [0.3, -0.5], [0.75, -0.4], [1.0, 0.0], [0.75, 0.4], [0.3, 0.5]]),
    np.array([[0.0, -0.5], [1.0, -0.5], [1.0, 0.5], [0.0, 0.5]]),
    np.array([[0.0, 0.0], [0.5, -0.5], [1.0, 0.0], [0.5, 0.5]]),
    np.array([[0.0, -0.5], [1.0, 0.0], [0.0, 0.5]]),
)
"""Leaf outlines in (along, across) leaf units, counter-clockwise seen from the leaf's upper side, in
the order of ``ipm.generators.trees.LEAF_SHAPES``."""
LEAF_THICKNESS = 0.05
"""Half thickness of a leaf lens, as a fraction of the smaller of leaf length and width."""


@dataclass(frozen=True)
class BranchGraph:
    """The tree's skeleton: segment joints and parent -> child edges, in the object frame."""

    positions: np.ndarray
    """Joint positions, shape (V, 3)."""
    radii: np.ndarray
    """Stem radius at each joint, shape (V,)."""
    edges: np.ndarray
    """Edges (parent joint, child joint), shape (E, 2); node 0 is the trunk base."""
    levels: np.ndarray
    """Stem level of each joint (0 trunk), shape (V,)."""
    n_leaves: int
    """Number of leaves on the tree."""

    @property
    def n_vertices(self) -> int:
        """Vertex count of the branch graph (the paper's complexity regulariser)."""
        return len(self.positions)


@dataclass
class Stems:
    """All stems of one level (clones included), sampled at ``res * substeps + 1`` points."""

    pos: np.ndarray  # (N, M+1, 3) sample points; samples before m0 repeat the start
    dirs: np.ndarray  # (N, M+1, 3) direction of travel from each sample
    xax: np.ndarray  # (N, M+1, 3) body x axis (ring frame), orthogonal to dirs
    rad: np.ndarray  # (N, M+1) radius
    j0: np.ndarray  # (N,) first segment (0 for stems, the split joint for clones)
    length: np.ndarray  # (N,) length of the whole stem
    r0: np.ndarray  # (N,) base radius
    mult: np.ndarray  # (N, S) share of children per segment (halved by splits)
    tpar: np.ndarray  # (N,) position on the parent (0..1); 1 for the trunk
    plen: np.ndarray  # (N,) length of the parent (1 for the trunk)
    lmax: np.ndarray  # (N,) drawn length factor (W-P length_child_max)
    parent: np.ndarray  # (N,) parent stem index in the previous level (-1 trunk)
    clone_of: np.ndarray  # (N,) stem this one split from (-1 for none)
    res: int
    sub: int

    def __len__(self) -> int:
        return len(self.j0)

    @property
    def m0(self) -> np.ndarray:
        return self.j0 * self.sub

    def at(self, idx: np.ndarray, t: np.ndarray):
        """Position, direction, x axis and radius of stems ``idx`` at relative length ``t``."""
        M = self.res * self.sub
        mf = np.clip(t * M, self.m0[idx], M - 1e-9)
        mi = np.floor(mf).astype(int)
        f = (mf - mi)[:, None]
        pos = self.pos[idx, mi] * (1 - f) + self.pos[idx, mi + 1] * f
        rad = self.rad[idx, mi] * (1 - f[:, 0]) + self.rad[idx, mi + 1] * f[:, 0]
        return pos, self.dirs[idx, mi], self.xax[idx, mi], rad


def unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` scaled to unit length (zero rows stay zero)."""
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product ``a x b`` of (..., 3) arrays."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


def rodrigues(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate rows of ``v`` about unit ``axis`` rows by ``angle`` (right-hand rule), Rodrigues."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * c + cross(axis, v) * s + axis * (np.sum(axis * v, 1)[:, None] * (1.0 - c))


def shape_ratio(shape: int, r: np.ndarray) -> np.ndarray:
    """W-P's ShapeRatio: relative branch length at ``r`` = distance from the top / crown height;
    ``shape`` indexes ``ipm.generators.trees.SHAPES``."""
    r = np.clip(r, 0.0, 1.0)
    if shape == 0:
        return 0.2 + 0.8 * r
    if shape == 1:
        return 0.2 + 0.8 * np.sin(np.pi * r)
    if shape == 2:
        return 0.2 + 0.8 * np.sin(0.5 * np.pi * r)
    if shape == 3:
        return np.ones_like(r)
    if shape == 4:
        return 0.5 + 0.5 * r
    if shape == 5:
        return np.where(r <= 0.7, r / 0.7, (1.0 - r) / 0.3)
    if shape == 6:
        return 1.0 - 0.8 * r
    return np.where(r <= 0.7, 0.5 + 0.5 * r / 0.7, 0.5 + 0.5 * (1.0 - r) / 0.3)


def curve_per_segment(res: int, curve: float, back: float) -> np.ndarray:
    """Deterministic turn (radians) of each segment about the stem's x axis (W-P 4.1)."""
    if back == 0.0:
        return np.full(res, np.radians(curve) / res)
    half = res / 2.0
    first = np.arange(res) < half
    return np.where(first, np.radians(curve) / half, np.radians(back) / half)


def tube_mesh(st: Stems, n_ring: int, charts: bool = True):
    """Closed tubes along every stem: rings at the samples from m0 on, flat caps at both ends.

    Returns vertices, faces, charts (``_tube_charts``; None without ``charts``) and normals
    (radial on rings, axial at caps).
    """
    M1 = st.rad.shape[1]
    M = M1 - 1
    si, mi = np.nonzero(np.arange(M1)[None, :] >= st.m0[:, None])
    R = len(si)
    P = st.pos[si, mi]
    prev_d = st.dirs[si, np.maximum(mi - 1, 0)]
    first = np.r_[True, si[1:] != si[:-1]]
    last = np.r_[si[1:] != si[:-1], True]
    T = np.where((first | last)[:, None], st.dirs[si, np.minimum(mi, M - 1)], unit(prev_d + st.dirs[si, mi]))
    T = unit(T)
    X = st.xax[si, mi]
    X = unit(X - np.sum(X * T, 1)[:, None] * T)
    Y = cross(T, X)
    th = 2 * np.pi * np.arange(n_ring) / n_ring
    out = np.cos(th)[None, :, None] * X[:, None] + np.sin(th)[None, :, None] * Y[:, None]
    ring = P[:, None] + st.rad[si, mi][:, None, None] * out
    verts = [ring.reshape(-1, 3)]
    base = np.arange(R) * n_ring
    kk, k1 = np.arange(n_ring), (np.arange(n_ring) + 1) % n_ring
    a = np.nonzero(~last)[0]
    A, A1 = base[a][:, None] + kk, base[a][:, None] + k1
    B, B1 = A + n_ring, A1 + n_ring
    side = np.concatenate([np.stack([A, B1, B], -1).reshape(-1, 3), np.stack([A, A1, B1], -1).reshape(-1, 3)])
    fi, li = np.nonzero(first)[0], np.nonzero(last)[0]
    cs = R * n_ring + np.arange(len(fi))
    ce = R * n_ring + len(fi) + np.arange(len(li))
    verts += [P[fi], P[li]]
    F0 = base[fi][:, None]
    L0 = base[li][:, None]
    cap_s = np.stack([np.repeat(cs, n_ring), (F0 + k1).ravel(), (F0 + kk).ravel()], -1)
    cap_e = np.stack([np.repeat(ce, n_ring), (L0 + kk).ravel(), (L0 + k1).ravel()], -1)
    normals = np.concatenate([out.reshape(-1, 3), -T[fi], T[li]])
    faces = np.concatenate([side, cap_s, cap_e])
    return (np.concatenate(verts), faces, _tube_charts(st, si, mi, a, fi, li, n_ring) if charts else None,
            normals)


def _tube_charts(st: Stems, si, mi, a, fi, li, n_ring: int):
    """Charts of ``tube_mesh``'s triangles, in its order: each stem's side unrolled (round its mean
    girth, along its arc length), each cap a disc. Returns the corners in their charts' frames
    (F, 3, 2), each triangle's chart (F,) and the charts' sizes (C, 2); charts are the stems' sides,
    then their start caps, then their end caps."""
    pos, rad = st.pos[si, mi], st.rad[si, mi]
    stems, first_ring = np.unique(si, return_index=True)
    step = np.r_[0.0, np.linalg.norm(pos[1:] - pos[:-1], axis=1)]
    step[first_ring] = 0.0
    arc = np.cumsum(step)
    arc -= arc[first_ring][np.searchsorted(stems, si)]
    stem = np.searchsorted(stems, si)  # each ring's stem, 0..S-1
    n_s = len(stems)
    girth = 2 * np.pi * np.maximum(np.bincount(stem, rad) / np.bincount(stem), 1e-4)
    length = np.maximum(np.maximum.reduceat(arc, first_ring), 1e-4)
    k = np.arange(n_ring)
    u = (k / n_ring)[None] * girth[stem[a]][:, None]
    u1 = ((k + 1) / n_ring)[None] * girth[stem[a]][:, None]
    v0 = np.broadcast_to(arc[a][:, None], u.shape)
    v1 = np.broadcast_to(arc[a + 1][:, None], u.shape)
    # the side's two triangle kinds, (A, B1, B) then (A, A1, B1), as tube_mesh lays them out
    side = [np.stack([np.stack([u, v0], -1), np.stack([u1, v1], -1), np.stack([u, v1], -1)], -2),
            np.stack([np.stack([u, v0], -1), np.stack([u1, v0], -1), np.stack([u1, v1], -1)], -2)]
    local = [x.reshape(-1, 3, 2) for x in side]
    chart = [np.repeat(stem[a], n_ring)] * 2
    theta = 2 * np.pi * k / n_ring
    for rings, order, offset in ((fi, (1, 0), n_s), (li, (0, 1), 2 * n_s)):
        r = np.maximum(rad[rings], 1e-4)[:, None]
        rim = np.stack([r * (1 + np.cos(theta)), r * (1 + np.sin(theta))], -1)  # (caps, n_ring, 2)
        nxt = np.roll(rim, -1, axis=1)
        centre = np.broadcast_to(np.concatenate([r, r], 1)[:, None], rim.shape)
        pair = (nxt, rim) if order == (1, 0) else (rim, nxt)
        local.append(np.stack([centre, *pair], -2).reshape(-1, 3, 2))
        chart.append(np.repeat(offset + stem[rings], n_ring))
    sizes = np.concatenate([np.stack([girth, length], -1),
                            *(np.repeat(2 * np.maximum(rad[rings], 1e-4)[:, None], 2, 1) for rings in (fi, li))])
    return np.concatenate(local), np.concatenate(chart), sizes


def leaf_mesh(base, along, across, nrm, shape: int, charts: bool = True):
    """Closed thin lenses: the outline plus an apex above and below its centre.

    Returns vertices, faces, charts (each leaf side's outline at its size; None without
    ``charts``) and normals: the apexes face up and down, rim vertices outwards in the leaf plane
    (the limit of the lens's area-weighted normals as it gets thin).
    """
    rim = LEAF_RIMS[shape]
    nr = len(rim)
    L = len(base)
    pts = base[:, None] + rim[None, :, 0:1] * along[:, None] + rim[None, :, 1:2] * across[:, None]
    centre = pts.mean(1)
    h = LEAF_THICKNESS * np.minimum(np.linalg.norm(along, axis=1), np.linalg.norm(across, axis=1))[:, None] * nrm
    verts = np.concatenate([pts, (centre + h)[:, None], (centre - h)[:, None]], 1).reshape(-1, 3)
    o = (np.arange(L) * (nr + 2))[:, None]
    i, i1 = np.arange(nr), (np.arange(nr) + 1) % nr
    front = np.stack([np.broadcast_to(o + nr, (L, nr)), o + i, o + i1], -1)
    back = np.stack([np.broadcast_to(o + nr + 1, (L, nr)), o + i1, o + i], -1)
    faces = np.concatenate([front, back], 1).reshape(-1, 3)
    n = unit(np.concatenate([unit(pts - centre[:, None]), nrm[:, None], -nrm[:, None]], 1)).reshape(-1, 3)
    if not charts:
        return verts, faces, None, n
    # charts: each leaf's upper and lower side its outline at its size (leaves 0..L-1 upper, L..2L-1 lower)
    extent = np.stack([np.linalg.norm(along, axis=1), np.linalg.norm(across, axis=1)], -1)  # (L, 2)
    flat = (rim - rim.min(0))[None] * extent[:, None]  # (L, nr, 2)
    middle = flat.mean(1, keepdims=True)
    upper = np.stack([np.broadcast_to(middle, flat.shape), flat, np.roll(flat, -1, axis=1)], -2)
    lower = np.stack([np.broadcast_to(middle, flat.shape), np.roll(flat, -1, axis=1), flat], -2)
    local = np.concatenate([upper, lower], 1).reshape(-1, 3, 2)
    chart = (np.arange(L)[:, None] + L * (np.arange(2 * nr) >= nr)[None]).ravel()  # each leaf's nr faces up, nr down
    sizes = np.tile(np.maximum(np.ptp(rim, 0)[None] * extent, 1e-4), (2, 1))
    return verts, faces, (local, chart, sizes), n


def graph_arrays(stems: list[Stems]):
    """Joints of every stem (clones share their split joint) and the edges between them."""
    pos, rad, lev, edges = [], [], [], []
    n_nodes = 0
    prev_nodes = None
    for level, st in enumerate(stems):
        S, k = st.res, st.sub
        nodes = np.full((len(st), S + 1), -1)
        own = np.arange(S + 1)[None, :] >= (st.j0 + (st.clone_of >= 0))[:, None]
        si, ji = np.nonzero(own)
        nodes[si, ji] = n_nodes + np.arange(len(si))
        n_nodes += len(si)
        pos.append(st.pos[si, ji * k])
        rad.append(st.rad[si, ji * k])
        lev.append(np.full(len(si), level))
        for i in np.nonzero(st.clone_of >= 0)[0]:  # clones were created after their source
            nodes[i, st.j0[i]] = nodes[st.clone_of[i], st.j0[i]]
        if level > 0:
            orig = st.clone_of < 0
            pj = np.minimum((st.tpar * stems[level - 1].res).astype(int), stems[level - 1].res)
            src = prev_nodes[st.parent, pj]
            # a joint below the parent's own start (a clone's) maps to the joint it split from
            bad = src < 0
            src[bad] = prev_nodes[st.parent[bad], np.argmax(prev_nodes[st.parent[bad]] >= 0, axis=1)]
            edges.append(np.stack([src[orig], nodes[orig, 0]], -1))
        a, b = nodes[:, :-1], nodes[:, 1:]
        ok = (a >= 0) & (b >= 0)
        edges.append(np.stack([a[ok], b[ok]], -1))
        prev_nodes = nodes
    return (np.concatenate(pos), np.concatenate(rad), np.concatenate(edges).astype(np.int64),
            np.concatenate(lev))
