"""Mesh recipes: shapes built by independent code (numpy, scipy, trimesh; no generator code), for
the out-of-family cases of ``datasets_synthetic``.

A recipe returns world-frame vertices (standing on y = 0, centred on the y axis), faces with
outward winding (Mitsuba's area emitters are one-sided), a part label per face and UVs (one a
vertex, or (F, 3, 2) one a corner, taken as they are); every part is closed, so the volumetric
metrics apply. Recipes with ``semantic_labels`` have the parts of that label map in order (label =
part + 1: trees branch, foliage; buildings wall, window, roof, door), and synth writes label images
for them. The trees' recipes are in
:mod:`datasets_synthetic.tree_recipes`, more cups and buildings in ``more_recipes`` and
``city_recipes``; :mod:`ipm.synth` imports them all.
"""
from __future__ import annotations

import numpy as np
import trimesh

from ipm.io.semantic import BUILDING_LABELS
from ipm.registry import Registry

RECIPES: Registry = Registry("mesh recipe")


def _cylindrical_uv(vertices: np.ndarray) -> np.ndarray:
    """UVs for meshes that have none: angle about +y and height."""
    u = (np.arctan2(vertices[:, 2], vertices[:, 0]) / (2 * np.pi)) % 1.0
    y = vertices[:, 1]
    return np.stack([u, (y - y.min()) / max(np.ptp(y), 1e-9)], 1)


@RECIPES.register("footed_cup")
def footed_cup(radius_bottom, radius_top, height, wall, foot_radius, foot_height,
               handle_reach, handle_low, handle_high, handle_radius, sections=96):
    """A cup on a foot ring with a three-bar handle: trimesh primitives, no dishes-generator code."""
    r0, r1, h = radius_bottom, radius_top, height
    prof = [[0.0, 0.0], [foot_radius, 0.0], [foot_radius, foot_height], [r0, foot_height + 0.01]]
    prof += [[r0 + (r1 - r0) * s ** 1.5, foot_height + 0.01 + (h - foot_height - 0.01) * s]
             for s in np.linspace(0.1, 1.0, 12)]
    prof += [[r1 - wall, h]]
    prof += [[r0 - wall + (r1 - r0) * s ** 1.5, foot_height + 0.04 + (h - foot_height - 0.04) * s]
             for s in np.linspace(0.95, 0.0, 12)]
    prof += [[0.0, foot_height + 0.04]]
    body = _revolved(prof, sections)

    def radius_at(y):
        s = np.clip((y - foot_height - 0.01) / (h - foot_height - 0.01), 0, 1)
        return r0 + (r1 - r0) * s ** 1.5

    y_lo, y_hi = handle_low * h, handle_high * h
    x_lo, x_hi = radius_at(y_lo) - wall / 2, radius_at(y_hi) - wall / 2
    x_out = max(x_lo, x_hi) + handle_reach
    bars = [((x_lo, y_lo), (x_out, y_lo)), ((x_out, y_lo), (x_out, y_hi)), ((x_hi, y_hi), (x_out, y_hi))]
    parts = [body]
    for (a, b) in bars:
        parts.append(trimesh.creation.cylinder(radius=handle_radius, segment=[[a[0], a[1], 0], [b[0], b[1], 0]],
                                               sections=24))
    for corner in ((x_out, y_lo), (x_out, y_hi)):
        parts.append(trimesh.creation.icosphere(2, handle_radius).apply_translation([corner[0], corner[1], 0]))
    return _assemble(parts, [0] + [1] * (len(parts) - 1))


def _closed_tubes(chains: list[tuple[np.ndarray, np.ndarray]], sides: int):
    """Closed tubes (rings along each polyline, fan caps at both ends, outward winding).

    ``chains``: (points (k, 3), radii (k,)) per tube, k >= 2. Ring frames are carried along each
    polyline by parallel transport, so tubes do not twist at bends.
    """
    verts, faces = [], []
    n_v = 0
    ang = 2 * np.pi * np.arange(sides) / sides
    k0, k1 = np.arange(sides), (np.arange(sides) + 1) % sides
    for pts, rad in chains:
        k = len(pts)
        seg = np.diff(pts, axis=0)
        seg /= np.linalg.norm(seg, axis=1, keepdims=True)
        tan = np.concatenate([seg[:1], seg[:-1] + seg[1:], seg[-1:]])
        tan /= np.linalg.norm(tan, axis=1, keepdims=True)
        ref = np.array([1.0, 0.0, 0.0]) if abs(tan[0, 0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        nrm = np.cross(tan[0], ref)
        nrm /= np.linalg.norm(nrm)
        rings = []
        for j in range(k):
            nrm = nrm - np.dot(nrm, tan[j]) * tan[j]  # parallel transport: keep the normal, drop its tangent part
            nrm /= np.linalg.norm(nrm)
            bin_ = np.cross(tan[j], nrm)
            rings.append(pts[j] + rad[j] * (np.cos(ang)[:, None] * nrm + np.sin(ang)[:, None] * bin_))
        ring_v = np.concatenate(rings)
        base = np.arange(k - 1)[:, None] * sides
        a, a1 = base + k0, base + k1
        b, b1 = a + sides, a1 + sides
        side = np.concatenate([np.stack([a, a1, b1], -1).reshape(-1, 3), np.stack([a, b1, b], -1).reshape(-1, 3)])
        c0, c1 = k * sides, k * sides + 1
        cap0 = np.stack([np.full(sides, c0), k1, k0], -1)
        cap1 = np.stack([np.full(sides, c1), (k - 1) * sides + k0, (k - 1) * sides + k1], -1)
        verts.append(np.concatenate([ring_v, pts[:1], pts[-1:]]))
        faces.append(np.concatenate([side, cap0, cap1]) + n_v)
        n_v += len(verts[-1])
    return np.concatenate(verts), np.concatenate(faces)


def _revolved(profile, sections: int) -> trimesh.Trimesh:
    """A closed solid of revolution about +y from a (radius, y) profile that starts and ends on the axis."""
    solid = trimesh.creation.revolve(np.asarray(profile, float)[::-1], sections=sections)
    solid.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # revolve's z -> y
    return solid


def _box(lo, hi, rotation=None) -> trimesh.Trimesh:
    """An axis-aligned box from corner ``lo`` to ``hi``, optionally turned about its centre."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    tf = np.eye(4)
    if rotation is not None:
        tf[:3, :3] = rotation
    tf[:3, 3] = 0.5 * (lo + hi)
    return trimesh.creation.box(extents=hi - lo, transform=tf)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perpendicular(d: np.ndarray, rng) -> np.ndarray:
    """Random unit vectors perpendicular to the unit vectors ``d`` (n, 3)."""
    r = rng.normal(size=d.shape)
    r -= np.sum(r * d, -1, keepdims=True) * d
    return _unit(r)


def _rotate(v: np.ndarray, axis: np.ndarray, angle) -> np.ndarray:
    """Rodrigues' rotation of ``v`` about the unit ``axis`` by ``angle`` (radians)."""
    c, s = np.cos(angle), np.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * np.dot(axis, v) * (1 - c)


def _along(pts: np.ndarray, spacing: float, start: float = 0.0):
    """Points every ``spacing`` along a polyline (from fraction ``start`` of its length) and the tangents there."""
    seg = np.diff(pts, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    total = cum[-1]
    t = np.arange(start * total + 0.5 * spacing, total, spacing)
    if len(t) == 0:
        t = np.array([0.5 * (1 + start) * total])
    i = np.clip(np.searchsorted(cum, t, side="right") - 1, 0, len(seg) - 1)
    w = ((t - cum[i]) / seg_len[i])[:, None]
    return pts[i] + w * seg[i], seg[i] / seg_len[i, None]


def _assemble(parts: list[trimesh.Trimesh], labels: list[int]):
    """Concatenate closed parts (each wound outwards) with one label per part."""
    for p in parts:
        trimesh.repair.fix_normals(p)  # outward winding: Mitsuba's area emitters are one-sided
    lab = np.concatenate([np.full(len(p.faces), k) for p, k in zip(parts, labels)])
    mesh = trimesh.util.concatenate(parts)
    return mesh.vertices, mesh.faces, lab, _cylindrical_uv(mesh.vertices)


@RECIPES.register("tankard_lid")
def tankard_lid(radius_bottom=0.3, radius_top=0.27, height=0.76, wall=0.025, floor=0.04, base_flare=0.025,
                rim_band=0.012, lid_overhang=0.025, lid_thickness=0.025, lid_gap=0.004, handle_reach=0.19,
                handle_low=0.2, handle_high=0.82, handle_radius=0.036, handle_squareness=3.0, thumb_angle_deg=35.0,
                sections=96):
    """A lidded tankard: a tapered body with a base moulding and rim band around an open cavity, a
    flat stepped lid resting on the rim (``lid_gap`` above it), a hinge (block, knuckle and lid tab)
    above the handle and a thumb-lift plate with a ball, and a thick D-shaped handle swept as a
    tube along a superellipse (``handle_squareness`` 2 is a half ellipse, larger is squarer).
    A revolved body like the dishes generator's, but the lid, hinge and thumb-lift are no part of
    its family. Labels: 0 body (lid, hinge and thumb-lift included), 1 handle.
    """
    h, r0, r1 = height, radius_bottom, radius_top

    def radius_at(y):
        return r0 + (r1 - r0) * np.clip(y / h, 0.0, 1.0)

    rb = r0 + base_flare
    prof = [[0.0, 0.0], [rb, 0.0], [rb, 0.035], [radius_at(0.06), 0.06]]
    prof += [[radius_at(y), y] for y in np.linspace(0.1, h - 0.04, 10)]
    prof += [[radius_at(h - 0.04) + rim_band, h - 0.035], [r1 + rim_band, h], [r1 - wall, h]]
    prof += [[radius_at(y) - wall, y] for y in np.linspace(h - 0.04, floor + 0.03, 10)]
    prof += [[radius_at(floor) - wall - 0.015, floor], [0.0, floor]]
    body = _revolved(prof, sections)

    y_lid = h + lid_gap
    r_lid = r1 + rim_band + lid_overhang
    t = lid_thickness
    lid = _revolved([[0.0, y_lid], [r_lid, y_lid], [r_lid, y_lid + t], [0.75 * r_lid, y_lid + t],
                     [0.68 * r_lid, y_lid + 1.6 * t], [0.0, y_lid + 1.6 * t]], sections)
    # hinge on the +x side, over the handle's upper end
    x_k = r_lid + 0.035  # knuckle axis
    r_k = 0.022
    y_k = y_lid + 0.5 * t
    tab = _box([r_lid - 0.06, y_lid, -0.045], [x_k, y_lid + t, 0.045])
    knuckle = trimesh.creation.cylinder(radius=r_k, segment=[[x_k, y_k, -0.06], [x_k, y_k, 0.06]], sections=24)
    block = _box([radius_at(h - 0.1) - 0.6 * wall, h - 0.1, -0.035], [x_k + 0.5 * r_k, y_k, 0.035])
    # thumb-lift: a plate leaning outwards from the knuckle, a ball on its top
    a = np.radians(thumb_angle_deg)
    plate_len = 0.11
    rot = trimesh.transformations.rotation_matrix(-a, [0, 0, 1])[:3, :3]  # lean towards +x
    centre = np.array([x_k, y_k, 0.0]) + 0.5 * plate_len * np.array([np.sin(a), np.cos(a), 0.0])
    plate = _box(centre - [0.009, 0.5 * plate_len, 0.03], centre + [0.009, 0.5 * plate_len, 0.03], rot)
    ball = trimesh.creation.icosphere(2, 0.024).apply_translation(
        [x_k + plate_len * np.sin(a), y_k + plate_len * np.cos(a), 0.0])

    # handle: a tube along a superellipse from the upper to the lower attachment (both mid-wall)
    y_hi, y_lo = handle_high * h, handle_low * h
    p_hi = np.array([radius_at(y_hi) - 0.5 * wall, y_hi])
    p_lo = np.array([radius_at(y_lo) - 0.5 * wall, y_lo])
    s = np.linspace(0.0, np.pi, 41)
    e = 2.0 / handle_squareness
    c, sn = np.cos(s), np.sin(s)
    w_lo = 0.5 * (1 - np.sign(c) * np.abs(c) ** e)  # 0 at the top, 1 at the bottom
    out = np.abs(sn) ** e
    xy = p_hi + w_lo[:, None] * (p_lo - p_hi) + (handle_reach + 0.5 * wall) * out[:, None] * [1.0, 0.0]
    pts = np.stack([xy[:, 0], xy[:, 1], np.zeros(len(s))], 1)
    rad = handle_radius * (1.0 - 0.2 * w_lo)  # thicker at the top, where the thumb rests
    hv, hf = _closed_tubes([(pts, rad)], 20)
    handle = trimesh.Trimesh(hv, hf, process=False)
    return _assemble([body, lid, tab, knuckle, block, plate, ball, handle], [0, 0, 0, 0, 0, 0, 0, 1])


@RECIPES.register("footed_goblet")
def footed_goblet(foot_radius=0.2, foot_thickness=0.022, stem_radius=0.028, stem_height=0.3, knot_radius=0.05,
                  knot_position=0.45, bowl_radius=0.26, bowl_height=0.42, rim_taper=0.12, wall=0.016, sections=96):
    """A goblet: a flat round foot with a low dome into the stem, a thin stem with a knot at
    ``knot_position`` of its height, and an open bowl (egg-shaped, drawn in by ``rim_taper`` at the
    rim) with a cavity of ``wall`` thickness. One solid of revolution, no handle; a shape the
    dishes generator's single-profile cups cannot take (a foot far narrower than the bowl on a
    long stem). Label 0 (body).
    """
    ft, sr = foot_thickness, stem_radius
    prof = [[0.0, 0.0], [foot_radius, 0.0], [foot_radius, 0.6 * ft], [foot_radius - 0.01, ft]]
    prof += [[sr + (foot_radius - 0.02 - sr) * (1 - q) ** 2, ft + 0.05 * q ** 1.5] for q in np.linspace(0.1, 1, 8)]
    y0 = ft + 0.05  # the stem proper starts here
    stem_top = y0 + stem_height
    for q in np.linspace(0.0, 1.0, 25)[1:]:
        y = y0 + q * stem_height
        bump = np.exp(-((q - knot_position) / 0.07) ** 2)
        prof.append([sr * (1 - 0.15 * q) + (knot_radius - sr) * bump, y])
    # the bowl: r(q) for q in [0, 1] from its bottom to the rim
    base_y = stem_top
    bowl = []
    for q in np.linspace(0.0, 1.0, 28)[1:]:
        r = bowl_radius * np.sin(0.5 * np.pi * min(q / 0.8, 1.0)) ** 0.7 * (1 - rim_taper * max(q - 0.6, 0) / 0.4)
        bowl.append([max(r, sr), base_y + 0.02 + q * (bowl_height - 0.02)])
    prof += bowl
    rim_y = bowl[-1][1]
    prof += [[bowl[-1][0] - wall, rim_y]]
    inner_floor = base_y + 0.06
    for q in np.linspace(1.0, 0.0, 28)[1:]:
        r = bowl_radius * np.sin(0.5 * np.pi * min(q / 0.8, 1.0)) ** 0.7 * (1 - rim_taper * max(q - 0.6, 0) / 0.4)
        y = base_y + 0.02 + q * (bowl_height - 0.02)
        if y <= inner_floor + 0.005:
            break
        prof.append([r - wall, y])
    prof += [[0.0, inner_floor]]
    body = _revolved(prof, sections)
    return _assemble([body], [0])


# Buildings: parts wall (0), window (1), roof (2), door (3), the order of BUILDING_LABELS.
_WALL, _WINDOW, _ROOF, _DOOR = range(4)


def _hull(points) -> trimesh.Trimesh:
    return trimesh.convex.convex_hull(np.asarray(points, float))


def _hip_roof(x0, x1, z0, z1, base, height, overhang) -> trimesh.Trimesh:
    """A hip roof over the rectangle [x0, x1] x [z0, z1]: four slopes of equal pitch meeting in a
    ridge along the longer side (a point over a square), the convex hull of eaves and ridge."""
    x0, x1, z0, z1 = x0 - overhang, x1 + overhang, z0 - overhang, z1 + overhang
    cx, cz = 0.5 * (x0 + x1), 0.5 * (z0 + z1)
    half = 0.5 * min(x1 - x0, z1 - z0)
    top = base + height
    if x1 - x0 >= z1 - z0:
        ridge = [[x0 + half, top, cz], [x1 - half, top, cz]]
    else:
        ridge = [[cx, top, z0 + half], [cx, top, z1 - half]]
    eaves = [[x, base, z] for x in (x0, x1) for z in (z0, z1)]
    return _hull(eaves + ridge)


def _facade_openings(start, end, normal, floors: int, storey: float, size, spacing: float, sill: float,
                     skip=lambda a: False, proud: float = 0.012):
    """Glass panes on the wall from point ``start`` to ``end`` (at y = 0) facing ``normal``: one
    row per storey, as many as fit ``spacing`` apart, each a thin box standing ``proud`` out of the
    wall plane (and as far into it); ``skip(a)`` drops the pane at position ``a`` along the wall."""
    start, end, normal = (np.asarray(v, float) for v in (start, end, normal))
    length = np.linalg.norm(end - start)
    along = (end - start) / length
    n = max(int(length // spacing), 0)
    panes = []
    for k in range(n):
        a = (k + 0.5) * length / n
        if skip(a):
            continue
        for f in range(floors):
            c = start + along * a + np.array([0.0, f * storey + sill + 0.5 * size[1], 0.0])
            half = 0.5 * size[0] * np.abs(along) + 0.5 * size[1] * np.array([0, 1, 0]) + proud * np.abs(normal)
            panes.append(_box(c - half, c + half))
    return panes


def _door(centre, size) -> list:
    """A door leaf standing proud of a wall facing +-z at ``centre`` (on the ground)."""
    c = np.asarray(centre, float)
    return [_box(c + [-0.5 * size[0], 0.0, -0.012], c + [0.5 * size[0], size[1], 0.012])]


@RECIPES.register("l_shaped_house")
def l_shaped_house(width=1.5, depth=0.8, wing_width=0.65, wing_depth=0.75, floors=2, storey=0.34,
                   roof_height=0.32, overhang=0.06, window=(0.13, 0.17), spacing=0.3, sill=0.09,
                   door=(0.15, 0.26)):
    """An L-shaped two-storey house: a main block and a wing coming forward at its right end, each
    under its own hip roof, glass panes standing proud of the walls and a door in the inner corner
    (boxes and convex hulls; no buildings-generator code)."""
    h = floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    wx0, wz1 = hx - wing_width, hz + wing_depth
    walls = [_box([-hx, 0, -hz], [hx, h, hz]), _box([wx0, 0, hz - 0.01], [hx, h, wz1])]
    roofs = [_hip_roof(-hx, hx, -hz, hz, h, roof_height, overhang),
             _hip_roof(wx0, hx, hz, wz1, h, roof_height, overhang)]
    door_a = wx0 - 0.22  # on the main front, beside the wing
    panes = []
    panes += _facade_openings([-hx, 0, hz], [wx0, 0, hz], [0, 0, 1], floors, storey, window, spacing, sill,
                              skip=lambda a: abs(-hx + a - door_a) < 0.5 * spacing)
    panes += _facade_openings([hx, 0, -hz], [-hx, 0, -hz], [0, 0, -1], floors, storey, window, spacing, sill)
    panes += _facade_openings([-hx, 0, -hz], [-hx, 0, hz], [-1, 0, 0], floors, storey, window, spacing, sill)
    panes += _facade_openings([hx, 0, wz1], [hx, 0, -hz], [1, 0, 0], floors, storey, window, spacing, sill)
    panes += _facade_openings([wx0, 0, wz1], [hx, 0, wz1], [0, 0, 1], floors, storey, window, spacing, sill)
    panes += _facade_openings([wx0, 0, hz], [wx0, 0, wz1], [-1, 0, 0], floors, storey, window, spacing, sill)
    doors = _door([door_a, 0.0, hz], door)
    parts = walls + roofs + panes + doors
    labels = [_WALL] * len(walls) + [_ROOF] * len(roofs) + [_WINDOW] * len(panes) + [_DOOR] * len(doors)
    return _assemble(parts, labels)


l_shaped_house.semantic_labels = BUILDING_LABELS


@RECIPES.register("tower_block")
def tower_block(width=1.0, depth=0.85, floors=7, storey=0.3, band=0.13, slab=0.04, penthouse=(0.55, 0.45, 0.3),
                side_windows=3, entrance=(0.35, 0.27)):
    """A flat-roofed tower block: ribbon windows along every storey of the front and back, single
    windows on the sides, a glazed entrance, a roof slab and a set-back penthouse with its own roof
    and ribbon window (boxes only; no buildings-generator code)."""
    h = floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    proud = 0.012
    walls = [_box([-hx, 0, -hz], [hx, h, hz])]
    panes, doors = [], []
    for f in range(1, floors):
        y0 = f * storey + 0.5 * (storey - band)
        for z in (hz, -hz):
            panes.append(_box([-hx + 0.06, y0, z - proud], [hx - 0.06, y0 + band, z + proud]))
    for x, normal in ((hx, 1.0), (-hx, -1.0)):
        panes += _facade_openings([x, 0, -hz], [x, 0, hz], [normal, 0, 0], floors, storey, (0.14, band),
                                  depth / side_windows, 0.5 * (storey - band))
    ex, ey = entrance
    doors.append(_box([-0.5 * ex, 0.0, hz - proud], [0.5 * ex, ey, hz + proud]))
    pw, pd, ph = penthouse
    px0, pz0 = hx - pw - 0.08, -hz + 0.08  # set back from the front, towards the back right
    roofs = [_box([-hx - 0.02, h, -hz - 0.02], [hx + 0.02, h + slab, hz + 0.02]),
             _box([px0 - 0.03, h + slab + ph, pz0 - 0.03], [px0 + pw + 0.03, h + 2 * slab + ph, pz0 + pd + 0.03])]
    walls.append(_box([px0, h + slab - 0.01, pz0], [px0 + pw, h + slab + ph, pz0 + pd]))
    panes.append(_box([px0 + 0.05, h + slab + 0.08, pz0 + pd - proud], [px0 + pw - 0.05, h + slab + 0.08 + band,
                                                                          pz0 + pd + proud]))
    parts = walls + roofs + panes + doors
    labels = [_WALL] * len(walls) + [_ROOF] * len(roofs) + [_WINDOW] * len(panes) + [_DOOR] * len(doors)
    return _assemble(parts, labels)


tower_block.semantic_labels = BUILDING_LABELS


def _gable_roof(x0, x1, z0, z1, base, height, overhang, ridge_along_z: bool = False) -> trimesh.Trimesh:
    """A gable roof over [x0, x1] x [z0, z1] with its ridge along x (along z with
    ``ridge_along_z``): the convex hull of the eaves and the ridge line."""
    x0, x1, z0, z1 = x0 - overhang, x1 + overhang, z0 - overhang, z1 + overhang
    eaves = [[x, base, z] for x in (x0, x1) for z in (z0, z1)]
    if ridge_along_z:
        return _hull(eaves + [[0.5 * (x0 + x1), base + height, z] for z in (z0, z1)])
    return _hull(eaves + [[x, base + height, 0.5 * (z0 + z1)] for x in (x0, x1)])


@RECIPES.register("row_houses")
def row_houses(widths=(0.7, 0.55), floors=(3, 2), depth=0.8, storey=0.32, roof_height=0.3, overhang=0.04,
               window=(0.12, 0.16), spacing=0.24, sill=0.08, door=(0.14, 0.25)):
    """Houses built wall to wall in a row, each with its own number of storeys, gable roof, glass
    panes standing proud of the front and back walls and a front door (boxes and convex hulls; no
    buildings-generator code)."""
    hz = 0.5 * depth
    x = -0.5 * sum(widths)
    parts, labels = [], []
    for w, n in zip(widths, floors):
        h = n * storey
        parts += [_box([x, 0, -hz], [x + w, h, hz]), _gable_roof(x, x + w, -hz, hz, h, roof_height, overhang)]
        labels += [_WALL, _ROOF]
        door_a = 0.5 * w
        front = _facade_openings([x, 0, hz], [x + w, 0, hz], [0, 0, 1], n, storey, window, spacing, sill,
                                 skip=lambda a, d=door_a: abs(a - d) < 0.5 * spacing)
        back = _facade_openings([x + w, 0, -hz], [x, 0, -hz], [0, 0, -1], n, storey, window, spacing, sill)
        parts += front + back
        labels += [_WINDOW] * (len(front) + len(back))
        parts += _door([x + door_a, 0.0, hz], door)
        labels.append(_DOOR)
        x += w
    return _assemble(parts, labels)


row_houses.semantic_labels = BUILDING_LABELS
