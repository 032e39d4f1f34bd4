"""Tree recipes: a space-colonisation broadleaf, a spruce-like conifer and a many-stemmed bush, built
by independent code (numpy and scipy; no generator code) as :mod:`datasets_synthetic.recipes`
builds the other out-of-family shapes, and registered in its ``RECIPES``. Parts: branch (0) and
foliage (1); synth writes semantic label images for them.
"""
from __future__ import annotations

import numpy as np

from datasets_synthetic.recipes import RECIPES, _along, _closed_tubes, _cylindrical_uv, _perpendicular, _rotate, _unit
from ipm.io.semantic import LABEL_NAMES


def _leaf_lenses(base: np.ndarray, along: np.ndarray, across: np.ndarray, normal: np.ndarray, thickness: float):
    """Closed diamond-shaped leaves: a rim of four points and an apex above and below the centre."""
    rim = np.stack([base, base + 0.5 * along + 0.5 * across, base + along, base + 0.5 * along - 0.5 * across], 1)
    centre = base + 0.5 * along
    up, down = centre + thickness * normal, centre - thickness * normal
    v = np.concatenate([rim, up[:, None], down[:, None]], 1).reshape(-1, 3)
    o = (np.arange(len(base)) * 6)[:, None]
    i, i1 = np.arange(4), (np.arange(4) + 1) % 4
    top = np.stack([np.broadcast_to(o + 4, (len(base), 4)), o + i1, o + i], -1)
    bottom = np.stack([np.broadcast_to(o + 5, (len(base), 4)), o + i, o + i1], -1)
    return v, np.concatenate([top, bottom], 1).reshape(-1, 3)


@RECIPES.register("space_colonisation_tree")
def space_colonisation_tree(trunk_height=0.45, crown_radius=0.5, crown_height=0.95, crown_flatten=0.3,
                            n_points=1500, influence=0.3, kill=0.07, step=0.035, up_tropism=0.15,
                            pipe_exponent=2.5, tip_radius=0.0035, twig_nodes=3, leaves_per_node=3,
                            leaf_length=0.075, leaf_width=0.045, sides=6, max_iterations=400, seed=0):
    """A tree grown by space colonisation (Runions, Lane and Prusinkiewicz 2007), numpy + scipy only.

    Attraction points fill a crown envelope (an ellipsoid of ``crown_radius`` and ``crown_height``
    above a bare trunk of ``trunk_height``, its lower part pressed flatter by ``crown_flatten``).
    From a root at the origin, each step every attraction point pulls its closest tree node
    within ``influence``; a pulled node grows a child ``step`` along the mean direction to its
    points (plus ``up_tropism`` towards the sky); points within ``kill`` of a node are removed.
    Branch radii follow the pipe model (``r_parent ** e = sum r_child ** e``) from ``tip_radius``.
    Branches are closed tubes (a chain follows its thickest child); closed diamond leaves
    (``leaves_per_node`` per node) sit on the last ``twig_nodes`` nodes of every twig.
    Returns world vertices (trunk base at the origin, standing on y = 0), faces, part labels
    (0 branch, 1 foliage) and UVs.
    """
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    centre_y = trunk_height + 0.5 * crown_height
    semi = np.array([crown_radius, 0.5 * crown_height, crown_radius])
    pts = np.empty((0, 3))
    while len(pts) < n_points:  # uniform in the envelope by rejection
        c = rng.uniform(-1.0, 1.0, (4 * n_points, 3))
        c = c[np.sum(c**2, 1) <= 1.0]
        c[:, 1] = np.where(c[:, 1] < 0, c[:, 1] * (1.0 - crown_flatten), c[:, 1])
        pts = np.concatenate([pts, c * semi + [0.0, centre_y, 0.0]])
    pts = pts[:n_points]
    nodes, parent = [np.zeros(3)], [-1]
    while nodes[-1][1] < trunk_height + 0.5 * influence:  # the bare trunk grows until the crown pulls it
        wobble = rng.normal(0.0, 0.08, 3) * [1.0, 0.0, 1.0]
        d = np.array([0.0, 1.0, 0.0]) + (wobble if len(nodes) > 2 else 0.0)
        nodes.append(nodes[-1] + step * d / np.linalg.norm(d))
        parent.append(len(nodes) - 2)
    up = np.array([0.0, 1.0, 0.0])
    for _ in range(max_iterations):
        if len(pts) == 0:
            break
        node_arr = np.array(nodes)
        dist, near = cKDTree(node_arr).query(pts, distance_upper_bound=influence)
        pulled = np.isfinite(dist)
        if not pulled.any():
            break
        pull = (pts[pulled] - node_arr[near[pulled]]) / dist[pulled, None]
        grow = np.zeros((len(nodes), 3))
        np.add.at(grow, near[pulled], pull)
        new = []
        for i in np.unique(near[pulled]):
            d = grow[i] / max(np.linalg.norm(grow[i]), 1e-9) + up_tropism * up
            norm = np.linalg.norm(d)
            if norm < 0.3:  # opposite pulls cancel: no growth here
                continue
            p = node_arr[i] + step * d / norm
            new.append(p)
            nodes.append(p)
            parent.append(int(i))
        if not new:
            break
        node_arr = np.array(nodes)
        d_kill, _ = cKDTree(node_arr).query(pts, distance_upper_bound=kill)
        pts = pts[~np.isfinite(d_kill)]
    nodes, parent = np.array(nodes), np.array(parent)
    n = len(nodes)
    children = [[] for _ in range(n)]
    for i in range(1, n):
        children[parent[i]].append(i)
    radius = np.full(n, tip_radius)
    for i in range(n - 1, 0, -1):  # children come after their parents
        if children[i]:
            radius[i] = np.sum(radius[children[i]] ** pipe_exponent) ** (1.0 / pipe_exponent)
    radius[0] = np.sum(radius[children[0]] ** pipe_exponent) ** (1.0 / pipe_exponent) * 1.15  # root flare
    # chains: each follows its thickest child; the other children start new chains at the fork
    chains, stack = [], [(0, [0])]
    while stack:
        i, chain = stack.pop()
        while children[i]:
            kids = sorted(children[i], key=lambda c: -radius[c])
            for c in kids[1:]:
                stack.append((c, [i, c]))
            i = kids[0]
            chain.append(i)
        if len(chain) >= 2:
            rad = radius[chain].copy()
            rad[0] = radius[chain[1]]  # a side branch starts with its own radius inside its parent
            chains.append((nodes[chain], rad))
    tv, tf = _closed_tubes(chains, sides)
    # leaves on the last twig_nodes nodes of every twig (a tip and its parents while they are thin)
    depth_to_tip = np.full(n, np.inf)
    for i in range(n - 1, -1, -1):
        depth_to_tip[i] = 0 if not children[i] else 1 + min(depth_to_tip[c] for c in children[i])
    holders = np.nonzero(depth_to_tip < twig_nodes)[0]
    holders = np.repeat(holders, leaves_per_node)
    m = len(holders)
    twig_dir = nodes[holders] - nodes[parent[holders]]
    twig_dir /= np.linalg.norm(twig_dir, axis=1, keepdims=True)
    along = twig_dir + rng.normal(0.0, 0.8, (m, 3))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    normal = up + rng.normal(0.0, 0.5, (m, 3))
    normal -= np.sum(normal * along, 1, keepdims=True) * along
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    across = np.cross(normal, along)
    size = rng.uniform(0.8, 1.2, (m, 1))
    lv, lf = _leaf_lenses(nodes[holders], along * leaf_length * size, across * leaf_width * size, normal,
                          0.05 * leaf_width)
    v = np.concatenate([tv, lv])
    f = np.concatenate([tf, lf + len(tv)])
    labels = np.concatenate([np.zeros(len(tf), int), np.ones(len(lf), int)])
    return v, f, labels, _cylindrical_uv(v)


space_colonisation_tree.semantic_labels = LABEL_NAMES
"""Its parts are branch (0) and foliage (1): synth writes semantic label images (semantic_scheme)."""


def _needles(sites: np.ndarray, tangents: np.ndarray, per_site: int, length: float, width: float,
             spread_deg: tuple[float, float], rng):
    """Closed needle-cluster lenses radiating from points on a twig, leaning forward along it."""
    base = np.repeat(sites, per_site, 0)
    tan = np.repeat(tangents, per_site, 0)
    side = _perpendicular(tan, rng)
    a = np.radians(rng.uniform(*spread_deg, (len(base), 1)))
    along = np.cos(a) * tan + np.sin(a) * side
    normal = _perpendicular(along, rng)
    across = np.cross(normal, along)
    size = rng.uniform(0.75, 1.25, (len(base), 1))
    return _leaf_lenses(base, along * length * size, across * width * size, normal, 0.12 * width)


@RECIPES.register("conifer_tree")
def conifer_tree(height=1.75, trunk_radius=0.035, crown_base=0.25, n_whorls=15, branches_per_whorl=6,
                 branch_length=0.6, length_exponent=1.1, droop_deg=20.0, tip_curl=0.3, branchlets_per_side=5,
                 branchlet_length=0.35, needle_spacing=0.028, needles_per_site=5, needle_length=0.055,
                 needle_width=0.012, sides=6, seed=0):
    """A spruce-like conifer: a straight trunk tapering to a leader at ``height``, ``n_whorls``
    whorls of ``branches_per_whorl`` branches from ``crown_base`` up, each whorl turned by the
    golden angle; branch length falls from ``branch_length`` at the bottom towards the top as
    ``((height - y) / (height - crown_base)) ** length_exponent`` (a conical crown). Branches leave
    the trunk ``droop_deg`` below horizontal and turn their tips up (``tip_curl``); alternate
    branchlets leave them on both sides; needle clusters (closed lenses) sit every
    ``needle_spacing`` along branchlets, the outer branches and the leader. Monopodial and
    whorled, unlike the trees generator's Weber-Penn recursion. Labels: 0 branch, 1 foliage.
    """
    rng = np.random.default_rng(seed)
    up = np.array([0.0, 1.0, 0.0])
    ys = np.linspace(0.0, height, 16)
    trunk = np.stack([np.zeros_like(ys), ys, np.zeros_like(ys)], 1)
    chains = [(trunk, trunk_radius * (1.0 - ys / height) ** 0.9 + 0.0015)]
    sites, tangents = [], []
    p, t = _along(trunk, needle_spacing, 0.88)  # the leader carries needles too
    sites.append(p)
    tangents.append(t)
    golden = np.pi * (3.0 - np.sqrt(5.0))
    whorl_y = crown_base + (height - 0.12 - crown_base) * np.linspace(0.0, 1.0, n_whorls)
    whorl_y[1:-1] += rng.uniform(-0.25, 0.25, n_whorls - 2) * (whorl_y[1] - whorl_y[0])
    s = np.linspace(0.0, 1.0, 8)
    for i, y0 in enumerate(whorl_y):
        rel = (height - y0) / (height - crown_base)
        n_b = max(3, int(round(branches_per_whorl * (0.6 + 0.4 * rel))))
        phase = i * golden + rng.uniform(0, 2 * np.pi / n_b)
        for k in range(n_b):
            phi = phase + 2 * np.pi * k / n_b + rng.normal(0.0, 0.12)
            length = max(0.04, branch_length * rel ** length_exponent * rng.uniform(0.85, 1.1))
            droop = np.radians(droop_deg * (0.3 + 0.7 * rel) + rng.normal(0.0, 3.0))
            out = np.array([np.cos(phi), 0.0, np.sin(phi)])
            lateral = np.cross(up, out)
            wander = rng.normal(0.0, 0.04) * np.sin(np.pi * s)
            pts = (np.array([0.0, y0, 0.0]) + length * s[:, None] * out + length * wander[:, None] * lateral
                   + length * (-np.tan(droop) * s + tip_curl * s ** 3)[:, None] * up)
            r_b = 0.45 * trunk_radius * (length / branch_length) ** 0.6 + 0.002
            chains.append((pts, r_b * (1.0 - 0.8 * s)))
            p, t = _along(pts, needle_spacing, 0.3)
            sites.append(p)
            tangents.append(t)
            # alternate branchlets on both sides, shorter towards the tip
            n_l = max(1, int(round(2 * branchlets_per_side * min(1.0, length / (0.6 * branch_length)))))
            for j, q in enumerate(np.linspace(0.15, 0.9, n_l)):
                side = 1.0 if j % 2 == 0 else -1.0
                jj = min(int(q * 7), 6)
                base = pts[jj] + (q * 7 - jj) * (pts[jj + 1] - pts[jj])
                tb = _unit(pts[jj + 1] - pts[jj])
                h = _unit(np.cross(up, tb)) * side
                d = _unit(np.cos(np.radians(50)) * tb + np.sin(np.radians(50)) * h - 0.15 * up)
                ll = branchlet_length * length * (1.0 - q) ** 0.6 * rng.uniform(0.8, 1.2)
                if ll < 0.02:
                    continue
                q3 = np.linspace(0.0, 1.0, 4)[:, None]
                bl = base + ll * q3 * d - 0.12 * ll * q3 ** 2 * up
                chains.append((bl, np.array([0.004, 0.0032, 0.0024, 0.0016]) * (0.6 + 0.4 * rel)))
                p, t = _along(bl, needle_spacing)
                sites.append(p)
                tangents.append(t)
    tv, tf = _closed_tubes(chains, sides)
    lv, lf = _needles(np.concatenate(sites), np.concatenate(tangents), needles_per_site, needle_length,
                      needle_width, (30.0, 80.0), rng)
    v = np.concatenate([tv, lv])
    f = np.concatenate([tf, lf + len(tv)])
    labels = np.concatenate([np.zeros(len(tf), int), np.ones(len(lf), int)])
    v[:, 1] -= v[:, 1].min()
    return v, f, labels, _cylindrical_uv(v)


conifer_tree.semantic_labels = LABEL_NAMES


@RECIPES.register("broad_bush")
def broad_bush(height=1.25, n_stems=7, stem_lean_deg=(15.0, 50.0), stem_length=0.42, fork_levels=4,
               fork_angle_deg=32.0, third_child=0.3, length_ratio=0.74, stem_radius=0.02, radius_ratio=0.68,
               up_tropism=0.2, spread=0.15, base_radius=0.08, twiglets_per_twig=6, twiglet_length=0.09,
               leaves_per_twiglet=8, leaf_length=0.07, leaf_width=0.04, sides=6, seed=0):
    """A broad multi-stemmed bush: ``n_stems`` stems rise from a root crown of ``base_radius``, lean
    outwards by ``stem_lean_deg`` (spread evenly round the crown) and fork ``fork_levels`` times (two children,
    a third with probability ``third_child``, each ``fork_angle_deg`` off the parent, pushed away
    from the axis by ``spread`` so the crown spreads into a dome wider than tall); every segment
    is a gently bent tube leaving its parent along the parent's tangent. The end twigs (and,
    half as many, the twigs before them) carry short twiglets and each twiglet a cluster of
    closed leaf lenses. Scaled to ``height``. No trunk, unlike the trees generator's trees.
    Labels: 0 branch, 1 foliage.
    """
    rng = np.random.default_rng(seed)
    up = np.array([0.0, 1.0, 0.0])
    chains, twigs = [], []
    q = np.linspace(0.0, 1.0, 6)[:, None]

    def grow(p0, t_in, d, length, radius, level):
        d = _unit(d + up_tropism * up)
        p2 = p0 + length * d
        p1 = p0 + 0.4 * length * t_in
        pts = (1 - q) ** 2 * p0 + 2 * q * (1 - q) * p1 + q ** 2 * p2  # quadratic Bezier, leaves along t_in
        pts += rng.normal(0.0, 0.02 * length, pts.shape) * np.sin(np.pi * q)
        chains.append((pts, radius * (1.0 - 0.3 * q[:, 0])))
        if level >= fork_levels - 1:
            twigs.append((pts, twiglets_per_twig if level == fork_levels else twiglets_per_twig // 2))
        if level == fork_levels:
            return
        t_out = _unit(pts[-1] - pts[-2])
        n_c = 3 if rng.random() < third_child else 2
        roll = rng.uniform(0, 2 * np.pi)
        outward = np.array([pts[-1, 0], 0.0, pts[-1, 2]])
        outward = outward / max(np.linalg.norm(outward), 1e-6)
        perp = _unit(np.cross(t_out, up) if abs(t_out[1]) < 0.99 else np.array([1.0, 0.0, 0.0]))
        for c in range(n_c):
            axis = _rotate(perp, t_out, roll + 2 * np.pi * c / n_c)
            ang = np.radians(fork_angle_deg * rng.uniform(0.7, 1.3))
            dc = _unit(_rotate(t_out, axis, ang) + spread * outward)
            grow(pts[-1], t_out, dc, length * length_ratio * rng.uniform(0.85, 1.15), radius * radius_ratio,
                 level + 1)

    phase = rng.uniform(0, 2 * np.pi)
    for k in range(n_stems):
        phi = phase + 2 * np.pi * k / n_stems + rng.normal(0.0, 0.2)
        out = np.array([np.cos(phi), 0.0, np.sin(phi)])
        lean = np.radians(rng.uniform(*stem_lean_deg))
        p0 = base_radius * rng.uniform(0.3, 1.0) * out
        grow(p0, up, np.cos(lean) * up + np.sin(lean) * out, stem_length * rng.uniform(0.8, 1.2),
             stem_radius * rng.uniform(0.8, 1.1), 0)
    # twiglets off the last half of every end twig, leaves clustered along each twiglet
    twiglets = []
    for pts, n_t in twigs:
        for _ in range(n_t):
            w = rng.uniform(0.4, 1.0)
            i = min(int(w * 5), 4)
            base = pts[i] + (w * 5 - i) * (pts[i + 1] - pts[i])
            t = _unit(pts[i + 1] - pts[i])
            d = _unit(t + 1.2 * _perpendicular(t[None], rng)[0] + 0.3 * up)
            tl = np.stack([base, base + 0.5 * twiglet_length * d, base + twiglet_length * d])
            chains.append((tl, np.array([0.0025, 0.002, 0.0015])))
            twiglets.append(tl)
    tv, tf = _closed_tubes(chains, sides)
    n_l = len(twiglets) * leaves_per_twiglet
    tw = np.repeat(np.array(twiglets), leaves_per_twiglet, 0)
    w = rng.uniform(0.2, 1.0, (n_l, 1))
    base = tw[:, 0] + w * (tw[:, 2] - tw[:, 0])
    tdir = _unit(tw[:, 2] - tw[:, 0])
    along = _unit(tdir + 0.9 * _perpendicular(tdir, rng))
    normal = _unit(up + rng.normal(0.0, 0.5, (n_l, 3)))
    normal = _unit(normal - np.sum(normal * along, 1, keepdims=True) * along)
    across = np.cross(normal, along)
    size = rng.uniform(0.8, 1.2, (n_l, 1))
    lv, lf = _leaf_lenses(base, along * leaf_length * size, across * leaf_width * size, normal, 0.05 * leaf_width)
    v = np.concatenate([tv, lv])
    f = np.concatenate([tf, lf + len(tv)])
    labels = np.concatenate([np.zeros(len(tf), int), np.ones(len(lf), int)])
    v[:, 1] -= v[:, 1].min()
    v *= height / v[:, 1].max()
    return v, f, labels, _cylindrical_uv(v)


broad_bush.semantic_labels = LABEL_NAMES
