"""Stochastic trees after Weber and Penn (1995), the rule-based generator of the paper's tree results.

A tree is a trunk (level 0) and up to three levels of recursive stems, then leaves on the
deepest stems. Every stem is a polyline of ``curve_res`` segments grown by a turtle:

1. **curvature** (W-P 4.1): each segment turns about the stem's own x axis by ``curve / res``
   (or ``curve / (res/2)`` in the first half and ``curve_back / (res/2)`` in the second when
   ``curve_back != 0``), plus a random turn of up to ``curve_v / res`` about a random axis
   (the trunk's first segment stays vertical, so the tree stands on its base);
2. **splits** (4.2): ``seg_splits`` clones per segment, spread evenly over the segments by error
   diffusion with a random phase per stem (``base_splits`` once on the trunk where the crown
   starts); the stem and its clones tilt away from each other by ``split_angle`` (minus the
   stem's declination, as in W-P) and half of that tilt is turned back over the remaining
   segments; branch clones are also spread about the vertical axis; after a split each stem
   carries a share of the children and of the cross-section (radius / sqrt(n));
3. **children** (4.3): level-1 stems sit on the trunk above ``base_size`` with lengths from the
   crown ``shape`` (W-P's ShapeRatio: conical, spherical, hemispherical, cylindrical, tapered
   cylindrical, flame, inverse conical, tend flame); deeper stems get
   ``length * (parent_length - 0.6 * offset)``; child counts follow W-P (level 2 from the parent's
   relative length, level 3 from its offset); children leave at ``down_angle`` (negative
   ``down_angle_v`` gives W-P's linear change along the parent) and turn about their parent by
   ``rotate`` per child (negative: alternating pairs), jittered by ``rotate_v``;
4. **radii** (4.4): trunk radius ``ratio * trunk length`` with root ``flare``; a child's radius is
   ``parent radius * (child length / parent length) ** ratio_power``, never above the parent's
   radius where it sits; ``taper`` narrows each stem towards its tip;
5. **attraction** (4.8): branches (levels >= 1) turn towards the sky by ``attract_up *
   declination / steps`` per step (negative values make weeping branches);
6. **leaves** (4.7): ``leaves`` per stem of the deepest level that grew (``levels``, or higher
   where a level has no branches), scaled by W-P's tapered-cylinder ratio of the
   stem's position on its parent, from ``leaf_start`` to the tip, at ``leaf_down_angle``, facing
   the sky, of size ``leaf_scale`` (fraction of the tree's height) x ``leaf_scale_x``.

Randomness comes from ``seed``: one numpy stream per (seed, level, purpose), drawn with stems on
the leading axis, so the parameters of a level never move the levels above it (the trunk and
level 1 stay put when level 3 changes) and a new seed reshuffles the whole tree. Like W-P, the
map is not continuous: a count that rounds differently, a split or a thinned child reshuffles
branches, so this generator is not differentiable (``differentiable = False``) and is meant for
the genetic search.

Geometry (stems as closed tubes, leaves as thin closed lenses, the branch graph) is in
``ipm.generators.trees_geometry``. Object frame: y up, trunk base at the origin (shifted up when
drooping branches reach below it, so the lowest point is y = 0), scaled to ``height``. Level of
detail sets the ring points per level and the turtle sub-steps per segment; the branching
structure (the branch graph) does not depend on it.

Complexity is capped (stems per level, leaves per tree, see ``MAX_STEMS`` and ``MAX_LEAVES``):
beyond a cap, counts are scaled down evenly, so random parameter vectors stay cheap. (Over 450
lines: W-P's growth is one algorithm over shared parameters, random streams and caps.)
"""
from __future__ import annotations

import numpy as np

from ipm.errors import UserError
from ipm.generators.base import GENERATORS, Generator, Mesh, make_spec
from ipm.generators.trees_geometry import (BranchGraph, Stems, cross, curve_per_segment, graph_arrays, leaf_mesh,
                                          rodrigues, shape_ratio, tube_mesh, unit)
from ipm.io.semantic import BRANCH, FOLIAGE, LABEL_NAMES
from ipm.uv import pack_parts

N_LEVELS = 3
"""Branch levels below the trunk (W-P ``Levels`` counts the trunk too)."""
SHAPES = ("conical", "spherical", "hemispherical", "cylindrical", "tapered_cylindrical", "flame",
          "inverse_conical", "tend_flame")
"""Crown shapes, in W-P's numbering (``shape`` parameter)."""
LEAF_SHAPES = ("oval", "rectangle", "diamond", "needle")
"""Leaf outlines (``leaf_shape`` parameter)."""
MAX_STEMS = (64, 400, 2000, 4000)
"""Most stems (with clones) per level: trunk, 1, 2, 3."""
MAX_LEAVES = 10000
"""Most leaves per tree."""
MIN_RADIUS = 2e-4
"""Smallest tube radius, as a fraction of the trunk length."""
SPLIT_RETURN = 0.5
"""Share of a split's tilt that the following segments turn back."""

# (turtle sub-steps per segment, ring points for trunk, level 1, 2, 3) per level of detail
_LOD = {0: (1, (6, 4, 3, 3)), 1: (2, (10, 6, 4, 4)), 2: (3, (16, 8, 6, 5))}

_BRANCHES_MAX = (60, 30, 15)
_LEVEL_DEFAULTS = (  # branches, length, down_angle, rotate, curve_res
    (25, 0.6, 60.0, 140.0, 4),
    (8, 0.45, 45.0, 140.0, 3),
    (4, 0.4, 45.0, 77.0, 2),
)


def _level_rows(n: int) -> list:
    b, length, down, rot, res = _LEVEL_DEFAULTS[n - 1]
    p = f"l{n}_"
    return [
        (p + "branches", 0, _BRANCHES_MAX[n - 1], True, b),
        (p + "length", 0.05, 1.5, False, length),
        (p + "length_v", 0.0, 0.5, False, 0.05),
        (p + "down_angle", 0.0, 150.0, False, down),
        (p + "down_angle_v", -90.0, 90.0, False, 10.0),
        (p + "rotate", -180.0, 180.0, False, rot),
        (p + "curve", -180.0, 180.0, False, 0.0),
        (p + "curve_back", -180.0, 180.0, False, 0.0),
        (p + "curve_v", 0.0, 360.0, False, 40.0),
        (p + "curve_res", 1, 10, True, res),
        (p + "seg_splits", 0.0, 1.0, False, 0.0),
    ]


_SPEC_ROWS = (
    [
        ("height", 0.5, 2.0, False, 1.2),  # final height of the tree (object units)
        ("shape", 0, 7, True, 4),  # crown shape, index into SHAPES
        ("base_size", 0.0, 0.8, False, 0.3),  # bare share of the trunk below the crown
        ("levels", 1, N_LEVELS, True, 2),  # branch levels below the trunk
        ("ratio", 0.005, 0.06, False, 0.025),  # trunk base radius / trunk length
        ("ratio_power", 0.5, 2.5, False, 1.3),  # child radius = parent radius * (length ratio) ** this
        ("flare", 0.0, 1.5, False, 0.4),  # root flare of the trunk
        ("taper", 0.0, 1.0, False, 0.9),  # branch taper (0 cylinder, 1 cone)
        ("attract_up", -2.0, 2.0, False, 0.3),  # upward (negative: downward) turn of branches
        ("rotate_v", 0.0, 60.0, False, 15.0),  # random jitter of child azimuths (degrees)
        ("seed", 0, 9999, True, 0),  # random stream
        ("trunk_taper", 0.0, 1.0, False, 0.8),
        ("trunk_curve", -90.0, 90.0, False, 0.0),  # degrees over the trunk
        ("trunk_curve_back", -90.0, 90.0, False, 0.0),
        ("trunk_curve_v", 0.0, 180.0, False, 20.0),
        ("trunk_curve_res", 2, 12, True, 6),  # trunk segments
        ("base_splits", 0, 4, True, 0),  # trunk forks where the crown starts
        ("trunk_seg_splits", 0.0, 1.5, False, 0.0),  # trunk clones per segment
        ("split_angle", 0.0, 90.0, False, 30.0),  # degrees between a stem and its clones
        ("split_angle_v", 0.0, 45.0, False, 10.0),
    ]
    + _level_rows(1) + _level_rows(2) + _level_rows(3)
    + [
        ("leaves", 0, 40, True, 8),  # leaves per deepest stem
        ("leaf_scale", 0.005, 0.15, False, 0.04),  # leaf length / tree height
        ("leaf_scale_x", 0.1, 1.5, False, 0.7),  # leaf width / leaf length
        ("leaf_shape", 0, len(LEAF_SHAPES) - 1, True, 0),  # index into LEAF_SHAPES
        ("leaf_start", 0.0, 0.9, False, 0.2),  # share of a stem below its first leaf
        ("leaf_down_angle", 0.0, 120.0, False, 45.0),  # degrees between leaf and stem
    ]
)

_UP = np.array([0.0, 1.0, 0.0])
_LEAF_LEVEL = N_LEVELS + 1
"""Stream level of the leaves."""
# random stream purposes: one stream per (seed, level, purpose), each drawn with stems (or leaves)
# on the leading axis, so that adding one more stem leaves the others' draws unchanged
(_S_TRUNK, _S_NOISE, _S_PHASE, _S_SPLIT, _S_PLACE, _S_CHILD, _S_AZ0, _S_AZJIT) = range(8)


def _rng(seed: int, level: int, purpose: int) -> np.random.Generator:
    return np.random.default_rng([seed, level, purpose])


class _Tree:
    """One evaluation: parameters by name, the random streams and the level-of-detail settings."""

    def __init__(self, p: dict, lod: int):
        self.p = p
        self.seed = int(p["seed"])
        self.sub, self.rings = _LOD[lod]

    # ---------------------------------------------------------------- growth of one level
    def grow(self, level: int, res: int, start: dict, cap: int) -> Stems:
        """Grow the stems of ``level`` from their starts (originals), splitting off clones."""
        p, k = self.p, self.sub
        if level == 0:
            curve, back, curve_v = p["trunk_curve"], p["trunk_curve_back"], p["trunk_curve_v"]
            rate, taper = p["trunk_seg_splits"], p["trunk_taper"]
        else:
            q = f"l{level}_"
            curve, back, curve_v = p[q + "curve"], p[q + "curve_back"], p[q + "curve_v"]
            rate, taper = p[q + "seg_splits"], p["taper"]
        turn = curve_per_segment(res, curve, back)
        noise_amp = np.radians(curve_v) / res
        attract = p["attract_up"] if level >= 1 else 0.0
        base_joint = min(max(1, int(round(p["base_size"] * res))), res - 1) if level == 0 else -1
        base_splits = int(p["base_splits"]) if level == 0 else 0
        split_deg, split_v = p["split_angle"], p["split_angle_v"]
        rng_noise, rng_split = _rng(self.seed, level, _S_NOISE), _rng(self.seed, level, _S_SPLIT)
        phase = _rng(self.seed, level, _S_PHASE).random(len(start["p"]))
        M = res * k
        seg_len_of = start["length"] / res

        n0 = len(start["p"])
        first = dict(p=start["p"], d=start["d"], x=start["x"], comp_axis=np.zeros((n0, 3)),
                     comp_rate=np.zeros(n0), phase=phase, mult=np.ones((n0, res)),
                     seg_len=seg_len_of, src=np.arange(n0), clone_of=np.full(n0, -1))
        pending: dict[int, list] = {0: [first]}
        out = []
        n_total = n0
        for j0 in range(res):
            if j0 not in pending:
                continue
            groups = pending.pop(j0)
            b = {key: np.concatenate([g[key] for g in groups]) for key in first}
            n = len(b["p"])
            ids = sum(len(o["j0"]) for o in out) + np.arange(n)
            u = rng_noise.random((n, res, 2))
            noise, psi = (u[..., 0] * 2.0 - 1.0) * noise_amp, u[..., 1] * (2 * np.pi)
            P = np.empty((n, M + 1, 3))
            D = np.empty((n, M + 1, 3))
            X = np.empty((n, M + 1, 3))
            P[:, : j0 * k + 1] = b["p"][:, None]
            cur_p, cur_d, cur_x = b["p"], b["d"], b["x"]
            comp_axis, comp_rate, mult = b["comp_axis"], b["comp_rate"], b["mult"].copy()
            for j in range(j0, res):
                if j > j0:  # splits at the joint that starts segment j
                    if j == base_joint and j0 == 0:
                        nsp = np.full(n, base_splits)
                    else:
                        ph = b["phase"]
                        nsp = (np.floor(ph + rate * j) - np.floor(ph + rate * (j - 1))).astype(int)
                    room = max(cap - n_total, 0)
                    if nsp.sum() > room:
                        nsp = np.minimum(nsp, np.maximum(room - (np.cumsum(nsp) - nsp), 0))
                    if nsp.any():
                        n_total += int(nsp.sum())
                        new = self._split(level, j, res, nsp, ids, cur_p, cur_d, cur_x, comp_axis, comp_rate,
                                          mult, b, split_deg, split_v, rng_split)
                        cur_d, cur_x, comp_axis, comp_rate, mult = new["orig"]
                        pending.setdefault(j, []).append(new["clones"])
                rooted = level == 0 and j == 0  # the trunk leaves the ground vertically
                for s in range(k):
                    m = j * k + s
                    if rooted:
                        D[:, m], X[:, m] = cur_d, cur_x
                        cur_p = cur_p + cur_d * (b["seg_len"] / k)[:, None]
                        P[:, m + 1] = cur_p
                        continue
                    ang = np.full(n, turn[j] / k)
                    cur_d = cur_d * np.cos(ang)[:, None] + cross(cur_x, cur_d) * np.sin(ang)[:, None]
                    if noise_amp > 0:
                        y = cross(cur_d, cur_x)
                        ax = cur_x * np.cos(psi[:, j])[:, None] + y * np.sin(psi[:, j])[:, None]
                        cur_d, cur_x = rodrigues(cur_d, ax, noise[:, j] / k), rodrigues(cur_x, ax, noise[:, j] / k)
                    if np.any(comp_rate != 0):
                        ax = unit(comp_axis - np.sum(comp_axis * cur_d, 1)[:, None] * cur_d)
                        cur_d, cur_x = rodrigues(cur_d, ax, comp_rate), rodrigues(cur_x, ax, comp_rate)
                    if attract != 0.0:
                        cosd = np.clip(cur_d[:, 1], -1.0, 1.0)
                        decl = np.arccos(cosd)
                        a = attract * decl / M
                        a = np.clip(a, -(np.pi - decl), decl)
                        ax = cross(cur_d, _UP)
                        ok = np.linalg.norm(ax, axis=1) > 1e-9
                        a = np.where(ok, a, 0.0)
                        ax = unit(ax)
                        cur_d, cur_x = rodrigues(cur_d, ax, a), rodrigues(cur_x, ax, a)
                    cur_d = unit(cur_d)
                    cur_x = unit(cur_x - np.sum(cur_x * cur_d, 1)[:, None] * cur_d)
                    D[:, m], X[:, m] = cur_d, cur_x
                    cur_p = cur_p + cur_d * (b["seg_len"] / k)[:, None]
                    P[:, m + 1] = cur_p
            D[:, M], X[:, M] = cur_d, cur_x
            if j0 > 0:
                D[:, : j0 * k], X[:, : j0 * k] = D[:, j0 * k][:, None], X[:, j0 * k][:, None]
            out.append(dict(P=P, D=D, X=X, mult=mult, src=b["src"], clone_of=b["clone_of"], j0=np.full(n, j0)))

        cat = {key: np.concatenate([o[key] for o in out]) for key in out[0]}
        src = cat["src"]
        length, r0 = start["length"][src], start["r0"][src]
        z = np.arange(M + 1) / M
        rad = r0[:, None] * np.maximum(1.0 - taper * z, 0.0)[None, :]
        if level == 0:
            yf = np.maximum(0.0, 1.0 - 8.0 * z)
            rad = rad * (p["flare"] * (100.0 ** yf - 1.0) / 100.0 + 1.0)[None, :]
        seg_of = np.minimum(np.arange(M + 1) // k, res - 1)
        rad = np.maximum(rad * np.sqrt(cat["mult"][:, seg_of]), MIN_RADIUS)
        return Stems(pos=cat["P"], dirs=cat["D"], xax=cat["X"], rad=rad, j0=cat["j0"], length=length, r0=r0,
                      mult=cat["mult"], tpar=start["tpar"][src], plen=start["plen"][src], lmax=start["lmax"][src],
                      parent=start["parent"][src], clone_of=cat["clone_of"],
                      res=res, sub=k)

    def _split(self, level, j, res, nsp, ids, cur_p, cur_d, cur_x, comp_axis, comp_rate, mult, b,
               split_deg, split_v, rng):
        """Tilt splitting stems and their new clones apart; return updated originals and clones."""
        k = self.sub
        who = np.nonzero(nsp)[0]
        cnt = nsp[who] + 1
        rep = np.repeat(who, cnt)
        c = np.arange(len(rep)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        tot = np.repeat(cnt, cnt)
        d, x = cur_d[rep], cur_x[rep]
        decl = np.degrees(np.arccos(np.clip(d[:, 1], -1.0, 1.0)))
        u = rng.random((len(rep), 2))
        w = rng.random((len(who), 2))
        ang = np.radians(np.maximum(split_deg + (2 * u[:, 0] - 1) * split_v - decl, 0.0))
        psi = np.repeat(w[:, 0] * 2 * np.pi, cnt) + 2 * np.pi * c / tot
        ax = x * np.cos(psi)[:, None] + cross(d, x) * np.sin(psi)[:, None]
        d, x = rodrigues(d, ax, ang), rodrigues(x, ax, ang)
        if level >= 1:  # spread about the vertical axis (W-P), alternating sides
            spread = np.radians(20.0 + 0.75 * (30.0 + np.abs(decl - 90.0)) * u[:, 1] ** 2)
            sign = np.where(c % 2 == 0, 1.0, -1.0) * np.repeat(np.where(w[:, 1] < 0.5, 1.0, -1.0), cnt)
            up = np.broadcast_to(_UP, d.shape)
            d, x = rodrigues(d, up, sign * spread), rodrigues(x, up, sign * spread)
        rate = -SPLIT_RETURN * ang / max((res - j) * k, 1)
        m = mult[rep].copy()
        m[:, j:] /= tot[:, None]
        orig = c == 0
        cur_d, cur_x, comp_axis, comp_rate, mult = (a.copy() for a in (cur_d, cur_x, comp_axis, comp_rate, mult))
        cur_d[who], cur_x[who], mult[who] = d[orig], x[orig], m[orig]
        comp_axis[who], comp_rate[who] = ax[orig], rate[orig]
        cl = ~orig
        rc = rep[cl]
        clones = dict(p=cur_p[rc], d=d[cl], x=x[cl], comp_axis=ax[cl], comp_rate=rate[cl], phase=b["phase"][rc],
                      mult=m[cl], seg_len=b["seg_len"][rc], src=b["src"][rc], clone_of=ids[rc])
        return {"orig": (cur_d, cur_x, comp_axis, comp_rate, mult), "clones": clones}

    # ---------------------------------------------------------------- attachment points
    def place(self, st: Stems, count: np.ndarray, t_lo: np.ndarray, level: int, purpose: int, cap: int):
        """Evenly jittered positions of ``count`` children per stem over [t_lo, 1], thinned after splits."""
        count = np.maximum(count, 0.0)
        if count.sum() > cap:
            count = count * (cap / count.sum())
        n = np.floor(count + 0.5).astype(int)
        rng = _rng(self.seed, level, purpose)
        tot = int(n.sum())
        idx = np.repeat(np.arange(len(n)), n)
        c = np.arange(tot) - np.repeat(np.cumsum(n) - n, n)
        jit, keep_u = rng.random((tot, 2)).T
        t = t_lo[idx] + (1 - t_lo[idx]) * (c + 0.5 + 0.8 * (jit - 0.5)) / n[idx]
        seg = np.minimum((t * st.res).astype(int), st.res - 1)
        keep = keep_u < st.mult[idx, seg]
        return idx[keep], c[keep], t[keep]

    def azimuth(self, st: Stems, idx, c, rotate: float, level: int):
        """Angles about the parent of its ``c``-th children: W-P's ``rotate`` (negative: alternating)."""
        phi0 = _rng(self.seed, level, _S_AZ0).random(len(st)) * 2 * np.pi
        jit = (_rng(self.seed, level, _S_AZJIT).random(len(idx)) * 2 - 1) * np.radians(self.p["rotate_v"])
        if rotate >= 0:
            step = c * np.radians(rotate)
        else:
            step = c * np.pi + (c // 2) * np.radians(180.0 + rotate)
        return phi0[idx] + step + jit

    def children(self, par: Stems, level: int) -> dict | None:
        """Starts of the level-``level`` stems on the stems ``par`` of the level above (W-P 4.3)."""
        p = self.p
        q = f"l{level}_"
        nb = p[q + "branches"]
        if nb <= 0 or len(par) == 0:
            return None
        S = par.res
        if level == 1:
            t_base = p["base_size"]
            full = np.full(len(par), nb)
        elif level == 2:
            t_base = 0.0
            full = nb * (0.2 + 0.8 * np.minimum(par.length / np.maximum(par.plen, 1e-9), 1.0)
                         / np.maximum(par.lmax, 1e-3))
        else:
            t_base = 0.0
            full = nb * (1.0 - 0.5 * par.tpar)
        t_lo = np.maximum(t_base, par.j0 / S)
        count = full * (1.0 - t_lo) / max(1.0 - t_base, 1e-6)
        idx, c, t = self.place(par, count, t_lo, level, _S_PLACE, MAX_STEMS[level])
        if len(idx) == 0:
            return None
        rng = _rng(self.seed, level, _S_CHILD)
        u = rng.random((len(idx), 2))
        lmax = np.maximum(p[q + "length"] + (2 * u[:, 0] - 1) * p[q + "length_v"], 0.0)
        plen = par.length[idx]
        if level == 1:
            length = plen * lmax * shape_ratio(int(p["shape"]), (1.0 - t) / max(1.0 - t_base, 1e-6))
        else:
            length = lmax * plen * (1.0 - 0.6 * t)
        pos, tan, xax, prad = par.at(idx, t)
        r0 = par.r0[idx] * (length / np.maximum(plen, 1e-9)) ** p["ratio_power"]
        r0 = np.maximum(np.minimum(r0, 0.95 * prad), MIN_RADIUS)
        da, dv = p[q + "down_angle"], p[q + "down_angle_v"]
        if dv >= 0:
            down = da + (2 * u[:, 1] - 1) * dv
        else:
            ratio = (1.0 - t) / max(1.0 - t_base, 1e-6)
            down = da + dv * (1.0 - 2.0 * shape_ratio(0, ratio))
        phi = self.azimuth(par, idx, c, p[q + "rotate"], level)
        yax = cross(tan, xax)
        radial = xax * np.cos(phi)[:, None] + yax * np.sin(phi)[:, None]
        dn = np.radians(down)[:, None]
        d = tan * np.cos(dn) + radial * np.sin(dn)
        x = unit(cross(tan, radial))
        keep = length > 1e-3
        if not keep.any():
            return None
        sel = lambda a: a[keep]  # noqa: E731
        return dict(p=sel(pos), d=unit(sel(d)), x=sel(x), length=sel(length), r0=sel(r0), tpar=sel(t),
                    plen=sel(plen), lmax=sel(lmax), parent=sel(idx))

    # ---------------------------------------------------------------- the whole tree
    def build(self):
        p = self.p
        levels = int(p["levels"])
        trunk_res = int(p["trunk_curve_res"])
        rng = _rng(self.seed, 0, _S_TRUNK)
        a = rng.random() * 2 * np.pi
        start = dict(p=np.zeros((1, 3)), d=_UP[None].copy(), x=np.array([[np.cos(a), 0.0, np.sin(a)]]),
                     length=np.ones(1), r0=np.array([p["ratio"]]), tpar=np.ones(1), plen=np.ones(1),
                     lmax=np.ones(1), parent=np.full(1, -1))
        stems = [self.grow(0, trunk_res, start, MAX_STEMS[0])]
        for level in range(1, levels + 1):
            start = self.children(stems[-1], level)
            if start is None:
                break
            stems.append(self.grow(level, int(p[f"l{level}_curve_res"]), start, MAX_STEMS[level]))
        return stems

    def leaves(self, st: Stems, size: float):
        """Leaf frames on the deepest stems: base point, along axis, across axis, normal."""
        p = self.p
        if p["leaves"] <= 0:
            return None
        n_per = p["leaves"] * (0.5 + 0.5 * np.clip(st.tpar, 0.0, 1.0))
        t_lo = np.maximum(p["leaf_start"], st.j0 / st.res)
        count = n_per * (1.0 - t_lo) / max(1.0 - p["leaf_start"], 1e-6)
        idx, c, t = self.place(st, count, t_lo, _LEAF_LEVEL, _S_PLACE, MAX_LEAVES)
        if len(idx) == 0:
            return None
        rng = _rng(self.seed, _LEAF_LEVEL, _S_CHILD)
        u = rng.random((len(idx), 2))
        pos, tan, xax, _ = st.at(idx, t)
        phi = self.azimuth(st, idx, c, 137.5, _LEAF_LEVEL)
        radial = xax * np.cos(phi)[:, None] + cross(tan, xax) * np.sin(phi)[:, None]
        dn = np.radians(p["leaf_down_angle"] + (2 * u[:, 0] - 1) * 15.0)[:, None]
        along = unit(tan * np.cos(dn) + radial * np.sin(dn))
        nrm = _UP - along[:, 1:2] * along
        bad = np.linalg.norm(nrm, axis=1) < 1e-3
        nrm[bad] = radial[bad]
        nrm = unit(nrm - np.sum(nrm * along, 1)[:, None] * along)
        twist = (2 * u[:, 1] - 1) * 0.5
        nrm = rodrigues(nrm, along, twist)
        across = cross(nrm, along)
        return pos, along * size, across * (size * p["leaf_scale_x"]), nrm


_SAMPLE_RANGES = {
    "height": (1.0, 1.7), "base_size": (0.05, 0.5), "levels": (2, 3), "ratio": (0.01, 0.04),
    "ratio_power": (1.0, 1.6), "flare": (0.0, 0.8), "taper": (0.7, 1.0), "attract_up": (-0.3, 0.8),
    "rotate_v": (0.0, 40.0), "trunk_taper": (0.6, 1.0), "trunk_curve": (-20.0, 20.0),
    "trunk_curve_back": (-20.0, 20.0), "trunk_curve_v": (0.0, 60.0), "trunk_curve_res": (3, 10),
    "base_splits": (0, 3), "trunk_seg_splits": (0.0, 0.4), "split_angle": (10.0, 50.0), "split_angle_v": (0.0, 20.0),
    **{f"l{n}_{k}": r for n, levels in ((1, {"branches": (10, 50), "length": (0.25, 0.9)}),
                                         (2, {"branches": (3, 12), "length": (0.2, 0.6)}),
                                         (3, {"branches": (2, 8), "length": (0.2, 0.6)}))
       for k, r in {**levels, "length_v": (0.0, 0.2), "down_angle": (20.0, 90.0), "down_angle_v": (-40.0, 20.0),
                    "rotate": (100.0, 160.0), "curve": (-40.0, 40.0), "curve_back": (-20.0, 20.0),
                    "curve_v": (0.0, 100.0), "curve_res": (2, 6), "seg_splits": (0.0, 0.3)}.items()},
    "leaves": (4, 25), "leaf_scale": (0.02, 0.08), "leaf_scale_x": (0.3, 1.2), "leaf_start": (0.0, 0.4),
    "leaf_down_angle": (20.0, 70.0),
}
"""Ranges of :meth:`Trees.sample` where they are narrower than the parameters' bounds: trees with
leaves and two or three branch levels, branches that leave their parent at 20-90 degrees and
bend moderately, trunks that stand, at most 1.7 tall (2 after the largest pose scale, the scene's
limit). Chosen from Weber and Penn's parameter meanings before any
reconstruction of a sampled tree; ``shape``, ``leaf_shape`` and ``seed`` are drawn over their
whole ranges."""


def _preset(spec, **values):
    x = spec.default.copy()
    for name, v in values.items():
        x[spec.index[name]] = v
    return x


def _levels(n, branches, length, length_v, down, down_v, rotate, curve, curve_back, curve_v, res, seg_splits):
    q = f"l{n}_"
    return {q + "branches": branches, q + "length": length, q + "length_v": length_v, q + "down_angle": down,
            q + "down_angle_v": down_v, q + "rotate": rotate, q + "curve": curve, q + "curve_back": curve_back,
            q + "curve_v": curve_v, q + "curve_res": res, q + "seg_splits": seg_splits}


def _uv(charts: list[tuple], labels: np.ndarray) -> np.ndarray:
    """Per-corner UVs of a tree's triangles: each part's charts (every stem's side and caps, every
    leaf's two sides; ``tube_mesh``, ``leaf_mesh``, in the faces' order) packed into its own square."""
    offsets = np.cumsum([0] + [len(c[2]) for c in charts[:-1]])
    chart = np.concatenate([c[1] + o for c, o in zip(charts, offsets)])
    return pack_parts(np.concatenate([c[0] for c in charts]), chart, np.concatenate([c[2] for c in charts]), labels)


@GENERATORS.register("trees")
class Trees(Generator):
    """Weber-Penn trees: trunk, up to three recursive branch levels and leaves; stochastic by ``seed``."""

    name = "trees"
    spec = make_spec(_SPEC_ROWS)
    part_names = ("branch", "foliage")
    plant = True
    semantic_labels = LABEL_NAMES
    part_semantic = (BRANCH, FOLIAGE)
    lods = tuple(_LOD)
    differentiable = False
    """No JAX positions function: the branching structure jumps with the parameters."""
    presets = {
        "oak": _preset(
            spec, height=1.6, shape=1, base_size=0.3, levels=3, ratio=0.035, ratio_power=1.3, flare=0.6, taper=0.9,
            attract_up=0.2, rotate_v=20.0, seed=11, trunk_taper=0.9, trunk_curve=0.0, trunk_curve_back=0.0,
            trunk_curve_v=40.0, trunk_curve_res=6, base_splits=2, trunk_seg_splits=0.0, split_angle=35.0,
            split_angle_v=10.0,
            **_levels(1, 22, 0.75, 0.1, 60.0, -25.0, 140.0, -30.0, 0.0, 80.0, 4, 0.25),
            **_levels(2, 10, 0.45, 0.1, 45.0, 15.0, 140.0, -20.0, 0.0, 60.0, 3, 0.0),
            **_levels(3, 5, 0.45, 0.1, 45.0, 10.0, 77.0, 0.0, 0.0, 40.0, 2, 0.0),
            leaves=7, leaf_scale=0.045, leaf_scale_x=0.7, leaf_shape=0, leaf_start=0.15, leaf_down_angle=40.0),
        "pine": _preset(
            spec, height=1.9, shape=0, base_size=0.15, levels=2, ratio=0.02, ratio_power=1.2, flare=0.3, taper=1.0,
            attract_up=0.15, rotate_v=25.0, seed=23, trunk_taper=1.0, trunk_curve=0.0, trunk_curve_back=0.0,
            trunk_curve_v=8.0, trunk_curve_res=10, base_splits=0, trunk_seg_splits=0.0, split_angle=0.0,
            split_angle_v=0.0,
            **_levels(1, 60, 0.38, 0.05, 85.0, -25.0, 137.5, -10.0, 0.0, 20.0, 4, 0.0),
            **_levels(2, 10, 0.35, 0.05, 55.0, 10.0, -90.0, 0.0, 0.0, 20.0, 2, 0.0),
            leaves=9, leaf_scale=0.035, leaf_scale_x=0.25, leaf_shape=3, leaf_start=0.0, leaf_down_angle=55.0),
        "poplar": _preset(
            spec, height=2.0, shape=7, base_size=0.2, levels=2, ratio=0.015, ratio_power=1.2, flare=0.3, taper=0.9,
            attract_up=0.6, rotate_v=20.0, seed=5, trunk_taper=0.9, trunk_curve=0.0, trunk_curve_back=0.0,
            trunk_curve_v=10.0, trunk_curve_res=8, base_splits=0, trunk_seg_splits=0.0, split_angle=20.0,
            split_angle_v=5.0,
            **_levels(1, 40, 0.3, 0.05, 25.0, 5.0, 140.0, -10.0, 0.0, 30.0, 4, 0.0),
            **_levels(2, 8, 0.45, 0.1, 35.0, 10.0, 140.0, 0.0, 0.0, 30.0, 2, 0.0),
            leaves=8, leaf_scale=0.03, leaf_scale_x=0.9, leaf_shape=2, leaf_start=0.1, leaf_down_angle=35.0),
        "bush": _preset(
            spec, height=0.8, shape=1, base_size=0.0, levels=2, ratio=0.03, ratio_power=1.2, flare=0.0, taper=0.9,
            attract_up=0.5, rotate_v=30.0, seed=7, trunk_taper=0.7, trunk_curve=0.0, trunk_curve_back=0.0,
            trunk_curve_v=40.0, trunk_curve_res=6, base_splits=4, trunk_seg_splits=0.3, split_angle=45.0,
            split_angle_v=10.0,
            **_levels(1, 20, 0.55, 0.1, 50.0, 10.0, 140.0, -20.0, 0.0, 60.0, 3, 0.0),
            **_levels(2, 8, 0.5, 0.1, 45.0, 10.0, 140.0, 0.0, 0.0, 40.0, 2, 0.0),
            leaves=12, leaf_scale=0.06, leaf_scale_x=0.7, leaf_shape=0, leaf_start=0.1, leaf_down_angle=45.0),
    }

    distance_ignores = ("seed",)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """A random plausible tree (the test split's sampler): each parameter uniform over
        ``_SAMPLE_RANGES`` (integers uniform over their values), else over its bounds."""
        spec = self.spec
        x = np.empty(len(spec))
        for i, name in enumerate(spec.names):
            lo, hi = _SAMPLE_RANGES.get(name, (spec.lower[i], spec.upper[i]))
            x[i] = rng.integers(int(lo), int(hi) + 1) if spec.discrete[i] else rng.uniform(lo, hi)
        return spec.clip(x)

    def active(self, x: np.ndarray) -> np.ndarray:
        """Levels below ``levels`` and, without leaves, the leaf parameters are inert."""
        p = self.spec.as_dict(self.spec.clip(x))
        on = np.ones(len(self.spec), bool)
        for i, name in enumerate(self.spec.names):
            if name[0] == "l" and name[1].isdigit() and int(name[1]) > p["levels"]:
                on[i] = False
            if name.startswith("leaf_") and p["leaves"] == 0:
                on[i] = False
        return on

    def preset(self, name: str) -> np.ndarray:
        """A copy of the parameter vector of preset ``name`` (``UserError`` if unknown)."""
        if name not in self.presets:
            raise UserError(f"unknown trees preset {name!r} (known: {', '.join(sorted(self.presets))})")
        return self.presets[name].copy()

    def positions_fn(self, key, lod):
        raise NotImplementedError("the trees generator is not differentiable: use generate() or mesh()")

    def generate(self, x: np.ndarray, lod: int = 1, uv: bool = True) -> tuple[Mesh, BranchGraph]:
        """The tree mesh (parts branch, foliage) and its branch graph for physical parameters ``x``;
        ``uv=False`` leaves the texture charts out (``Mesh.uv`` None: a search's evaluations)."""
        x = np.asarray(x, np.float64)
        if x.shape != (len(self.spec),) or not np.all(np.isfinite(x)):
            raise UserError(f"trees need {len(self.spec)} finite parameters, got shape {x.shape}")
        if lod not in _LOD:
            raise UserError(f"unknown level of detail {lod!r} (known: {', '.join(map(str, _LOD))})")
        p = self.spec.as_dict(self.spec.clip(x))
        tree = _Tree(p, int(lod))
        stems = tree.build()
        verts, faces, charts, labels, normals = [], [], [], [], []
        n_v = 0
        for level, st in enumerate(stems):
            v, f, chart, n = tube_mesh(st, tree.rings[level], uv)
            verts.append(v)
            faces.append(f + n_v)
            charts.append(chart)
            normals.append(n)
            labels.append(np.zeros(len(f), np.int32))
            n_v += len(v)
        bv = np.concatenate(verts)
        lo, hi = bv[:, 1].min(), bv[:, 1].max()
        leaf = tree.leaves(stems[-1], p["leaf_scale"] * (hi - lo))
        n_leaves = 0
        if leaf is not None:
            v, f, chart, n = leaf_mesh(*leaf, int(p["leaf_shape"]), uv)
            verts.append(v)
            faces.append(f + n_v)
            charts.append(chart)
            normals.append(n)
            labels.append(np.ones(len(f), np.int32))
            n_leaves = len(leaf[0])
        v = np.concatenate(verts)
        f = np.concatenate(faces).astype(np.int64)
        lo, hi = v[:, 1].min(), v[:, 1].max()
        scale = p["height"] / max(hi - lo, 1e-9)
        shift = np.array([0.0, -lo, 0.0])
        v = (v + shift) * scale
        labels = np.concatenate(labels)
        mesh = Mesh(v, f, np.concatenate(normals), _uv(charts, labels) if uv else None, labels, self.part_names)
        gp, gr, ge, gl = graph_arrays(stems)
        graph = BranchGraph((gp + shift) * scale, gr * scale, ge, gl, n_leaves)
        return mesh, graph

    def mesh(self, x: np.ndarray, lod: int = 1, uv: bool = True) -> Mesh:
        """The tree mesh for physical parameters ``x`` (numpy only; no JAX; ``uv=False``: without
        texture coordinates)."""
        return self.generate(x, lod, uv)[0]

    def branch_graph(self, x: np.ndarray, lod: int = 0) -> BranchGraph:
        """The branch graph alone (its node count does not depend on ``lod``)."""
        return self.generate(x, lod, uv=False)[1]
