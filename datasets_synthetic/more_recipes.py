"""More mesh recipes for out-of-family cases: a mug with a round C handle, a footed bowl, a teacup
with an ear handle, a tapered stein with a D handle, an egg cup, a sundae cup, a cocktail glass, a
champagne flute, a house with a lean-to annex and a T-shaped house. Independent code as in
:mod:`datasets_synthetic.recipes` (numpy and trimesh, no generator code), registered in its
``RECIPES``; each part closed, wound outwards."""
from __future__ import annotations

import numpy as np
import trimesh

from datasets_synthetic.recipes import (_DOOR, _ROOF, _WALL, _WINDOW, RECIPES, _assemble, _box, _closed_tubes, _door,
                                        _facade_openings, _gable_roof, _hull, _revolved)
from ipm.io.semantic import BUILDING_LABELS


@RECIPES.register("c_handle_mug")
def c_handle_mug(radius=0.3, height=0.72, wall=0.022, floor=0.035, base_round=0.05, handle_low=0.2,
                 handle_high=0.78, handle_reach=0.19, handle_radius=0.03, sections=96):
    """A straight-sided mug with a rounded base edge and a round C-shaped handle: a tube swept
    along a half ellipse from the wall at ``handle_low`` to ``handle_high`` of the height (a
    revolved body and a swept tube; labels 0 body, 1 handle)."""
    t = np.linspace(-0.5 * np.pi, 0.0, 8)  # the base edge's quarter circle
    prof = [[0.0, 0.0]] + [[radius - base_round + base_round * np.cos(a), base_round + base_round * np.sin(a)]
                           for a in t]
    prof += [[radius, height], [radius - wall, height], [radius - wall, floor + base_round],
             [radius - wall - 0.5 * base_round, floor], [0.0, floor]]
    body = _revolved(prof, sections)
    s = np.linspace(0.0, 1.0, 33)
    x0 = radius - 0.5 * wall  # the handle's ends sit in the wall
    y0, y1 = handle_low * height, handle_high * height
    pts = np.stack([x0 + handle_reach * np.sin(np.pi * s), y0 + (y1 - y0) * 0.5 * (1 - np.cos(np.pi * s)),
                    np.zeros_like(s)], 1)
    v, f = _closed_tubes([(pts, np.full(len(pts), handle_radius))], sides=20)
    return _assemble([body, trimesh.Trimesh(v, f, process=False)], [0, 1])


@RECIPES.register("ear_teacup")
def ear_teacup(radius=0.38, height=0.46, base_radius=0.17, foot_height=0.035, wall=0.018, bell=1.6,
               handle_top=0.85, handle_bottom=0.3, handle_reach=0.2, handle_radius=0.026, sections=96):
    """A teacup whose side flares from a foot ring as a bell (the radius grows as the height's
    ``bell`` power), with a small ear handle: a tube swept along a teardrop from near the rim down
    to the lower body, widest near its top (a revolved body and a swept tube; labels 0 body, 1 handle)."""
    def radius_of(s):  # s: the share of the side's height above the foot
        return base_radius + (radius - base_radius) * s ** bell

    s = np.linspace(0.0, 1.0, 20)
    rise = foot_height + (height - foot_height) * s
    out_r = radius_of(s)
    prof = [[0.0, 0.0], [base_radius * 0.9, 0.0], [base_radius * 0.9, foot_height]]
    prof += [[r, y] for r, y in zip(out_r, rise)]
    prof += [[r - wall, y] for r, y in zip(out_r[::-1], rise[::-1]) if y > foot_height + wall]
    prof += [[0.0, foot_height + wall]]
    body = _revolved(prof, sections)

    t = np.linspace(0.0, 1.0, 41)
    y = height * (handle_top + (handle_bottom - handle_top) * t)
    bulge = np.sin(np.pi * t) * (1.0 - 0.45 * t)  # a teardrop: widest in its upper half
    side = radius_of(np.clip((y - foot_height) / (height - foot_height), 0, 1))
    pts = np.stack([side - 0.5 * wall + handle_reach * bulge, y, np.zeros_like(t)], 1)
    v, f = _closed_tubes([(pts, np.full(len(pts), handle_radius))], sides=16)
    return _assemble([body, trimesh.Trimesh(v, f, process=False)], [0, 1])


@RECIPES.register("d_handle_stein")
def d_handle_stein(radius_bottom=0.33, radius_top=0.26, height=0.82, wall=0.024, base_band=0.06,
                   handle_low=0.18, handle_high=0.84, handle_reach=0.2, corner=0.07, handle_radius=0.032,
                   sections=96):
    """A stein narrowing to the top over a thicker base band, with a D handle: a tube out from the
    wall, down a straight grip and back, its two bends rounded with radius ``corner`` (a revolved
    body and a swept tube; labels 0 body, 1 handle)."""
    def radius_at(y):
        return radius_bottom + (radius_top - radius_bottom) * np.clip(y / height, 0, 1)

    band = radius_bottom + 0.015
    prof = [[0.0, 0.0], [band, 0.0], [band, base_band], [radius_at(base_band), base_band], [radius_top, height]]
    prof += [[radius_top - wall, height], [radius_bottom - wall, base_band + wall], [0.0, base_band + wall]]
    body = _revolved(prof, sections)
    y0, y1 = handle_low * height, handle_high * height
    x_out = max(radius_at(y0), radius_at(y1)) + handle_reach
    arc = np.linspace(0.0, 0.5 * np.pi, 9)
    top = [[radius_at(y1) - 0.5 * wall + (x_out - corner - radius_at(y1)) * s, y1] for s in np.linspace(0, 1, 6)]
    top += [[x_out - corner + corner * np.sin(a), y1 - corner + corner * np.cos(a)] for a in arc[1:]]
    down = [[x_out, y] for y in np.linspace(y1 - corner, y0 + corner, 10)[1:-1]]
    bottom = [[x_out - corner + corner * np.cos(a), y0 + corner - corner * np.sin(a)] for a in arc[:-1]]
    bottom += [[x_out - corner - (x_out - corner - radius_at(y0) + 0.5 * wall) * s, y0] for s in np.linspace(0, 1, 6)]
    path = np.array(top + down + bottom)
    pts = np.concatenate([path, np.zeros((len(path), 1))], 1)
    v, f = _closed_tubes([(pts, np.full(len(pts), handle_radius))], sides=20)
    return _assemble([body, trimesh.Trimesh(v, f, process=False)], [0, 1])


@RECIPES.register("footed_bowl")
def footed_bowl(radius=0.46, height=0.32, wall=0.02, foot_radius=0.19, foot_height=0.04, flare=0.7,
                sections=96):
    """A wide bowl on a foot ring, its side rising from the foot as a quarter sine bent by
    ``flare`` (smaller opens it faster), a rounded lip, no handle (a revolved body; label 0)."""
    s = np.linspace(0.0, 1.0, 16)
    rise = foot_height + (height - foot_height) * s
    out_r = foot_radius + (radius - foot_radius) * np.sin(0.5 * np.pi * s) ** flare
    prof = [[0.0, 0.0], [foot_radius, 0.0]] + [[r, y] for r, y in zip(out_r, rise)]
    lip = np.linspace(0.0, np.pi, 7)[1:-1]
    prof += [[radius - 0.5 * wall + 0.5 * wall * np.cos(a), height + 0.5 * wall * np.sin(a)] for a in lip]
    inner = [[r - wall, y] for r, y in zip(out_r[::-1], rise[::-1]) if r - wall > 0 and y > foot_height + wall]
    prof += inner + [[0.0, foot_height + wall]]
    return _assemble([_revolved(prof, sections)], [0])


@RECIPES.register("egg_cup")
def egg_cup(foot_radius=0.17, foot_thickness=0.018, stem_radius=0.055, stem_top=0.2, cup_radius=0.22,
            collar=0.06, wall=0.018, sections=96):
    """An egg cup: a disc foot flaring into a short trumpet stem, a round cup (a sphere's lower part
    up to its equator) with a straight collar above, a cavity of ``wall`` thickness, no handle (a
    revolved body; label 0)."""
    ft, sr, r = foot_thickness, stem_radius, cup_radius
    prof = [[0.0, 0.0], [foot_radius, 0.0], [foot_radius, ft]]
    prof += [[sr + (foot_radius - sr) * (1 - q) ** 2.5, ft + q * (stem_top - ft)] for q in np.linspace(0.08, 1, 12)]
    start = np.arcsin(sr / r)
    centre = stem_top + r * np.cos(start)
    prof += [[r * np.sin(a), centre - r * np.cos(a)] for a in np.linspace(start, 0.5 * np.pi, 14)[1:]]
    rim = centre + collar
    prof += [[r, rim], [r - wall, rim], [r - wall, centre]]
    prof += [[(r - wall) * np.sin(a), centre - (r - wall) * np.cos(a)] for a in np.linspace(0.5 * np.pi, 0.0, 14)[1:]]
    return _assemble([_revolved(prof, sections)], [0])


@RECIPES.register("sundae_cup")
def sundae_cup(foot_radius=0.25, foot_thickness=0.03, stem_radius=0.06, stem_height=0.14, bowl_radius=0.42,
               bowl_height=0.3, wall=0.02, sections=96):
    """A sundae cup: a flat disc foot, a short straight stem and a wide cone bowl opening upwards
    (its side slightly bellied), a cavity of ``wall`` thickness, no handle (a revolved body;
    label 0)."""
    ft, sr = foot_thickness, stem_radius
    y0 = ft + stem_height
    prof = [[0.0, 0.0], [foot_radius, 0.0], [foot_radius, ft], [sr + 0.02, ft], [sr, ft + 0.02], [sr, y0]]
    q = np.linspace(0.0, 1.0, 16)[1:]
    out_r = sr + (bowl_radius - sr) * q ** 0.85
    prof += [[rr, y0 + qq * bowl_height] for rr, qq in zip(out_r, q)]
    floor = y0 + 0.06
    inner = [[rr - wall, y0 + qq * bowl_height] for rr, qq in zip(out_r[::-1], q[::-1])
             if y0 + qq * bowl_height > floor and rr - wall > 0]
    prof += inner + [[0.0, floor]]
    return _assemble([_revolved(prof, sections)], [0])


@RECIPES.register("cocktail_glass")
def cocktail_glass(foot_radius=0.22, foot_rise=0.035, stem_radius=0.022, stem_height=0.34, bowl_radius=0.4,
                   bowl_height=0.3, wall=0.014, sections=96):
    """A cocktail glass: a foot sloping up as a shallow cone to a long straight thin stem and a
    V-shaped cone bowl with straight sides, a cavity of ``wall`` thickness, no handle (a revolved
    body; label 0)."""
    sr = stem_radius
    prof = [[0.0, 0.0], [foot_radius, 0.0], [foot_radius, 0.01]]
    prof += [[sr + (foot_radius - sr) * (1 - q), 0.01 + foot_rise * q ** 0.7] for q in np.linspace(0.1, 1, 8)]
    y0 = 0.01 + foot_rise + stem_height
    prof += [[sr, y0]]
    prof += [[sr + (bowl_radius - sr) * q, y0 + q * bowl_height] for q in np.linspace(0.05, 1.0, 12)]
    floor = y0 + 0.04
    slope = bowl_height / (bowl_radius - sr)
    prof += [[(y - y0) / slope + sr - wall * 1.2, y] for y in np.linspace(y0 + bowl_height, floor + 0.01, 10)]
    prof += [[0.0, floor]]
    return _assemble([_revolved(prof, sections)], [0])


@RECIPES.register("flute_glass")
def flute_glass(foot_radius=0.17, foot_thickness=0.014, stem_radius=0.02, stem_height=0.3, bowl_radius=0.12,
                bowl_height=0.5, wall=0.012, sections=96):
    """A champagne flute: a flat thin disc foot, a long thin stem widening at both ends, and a tall
    narrow bowl (round at its base, a slight belly, drawn in towards the rim), a cavity of
    ``wall`` thickness, no handle (a revolved body; label 0)."""
    ft, sr = foot_thickness, stem_radius
    prof = [[0.0, 0.0], [foot_radius, 0.0], [foot_radius, ft]]
    ys = np.linspace(0.0, 1.0, 14)
    prof += [[sr * (1 + 1.2 * (1 - q) ** 6 + 0.8 * q ** 8), ft + q * stem_height] for q in ys]
    y0 = ft + stem_height
    q = np.linspace(0.0, 1.0, 24)[1:]
    out_r = bowl_radius * (np.sin(0.5 * np.pi * np.minimum(q / 0.3, 1.0)) ** 0.8) * (1 - 0.15 * np.maximum(q - 0.55, 0) / 0.45)
    out_r = np.maximum(out_r, 1.6 * sr)
    prof += [[rr, y0 + qq * bowl_height] for rr, qq in zip(out_r, q)]
    floor = y0 + 0.06
    prof += [[rr - wall, y0 + qq * bowl_height] for rr, qq in zip(out_r[::-1], q[::-1])
             if y0 + qq * bowl_height > floor + 0.005 and rr - wall > 0]
    prof += [[0.0, floor]]
    return _assemble([_revolved(prof, sections)], [0])


def _centred(walls, roofs, panes, doors):
    """A building's parts labelled and moved so that its walls' footprint is centred on the y axis."""
    lo = np.min([w.bounds[0] for w in walls], axis=0)
    hi = np.max([w.bounds[1] for w in walls], axis=0)
    parts = [p.apply_translation([-0.5 * (lo[0] + hi[0]), 0.0, -0.5 * (lo[2] + hi[2])])
             for p in walls + roofs + panes + doors]
    labels = [_WALL] * len(walls) + [_ROOF] * len(roofs) + [_WINDOW] * len(panes) + [_DOOR] * len(doors)
    return _assemble(parts, labels)


def _lean_to(x0, x1, z0, z1, low, high, overhang, thickness=0.04):
    """A lean-to against the wall at x = x0: its walls (a convex block whose top falls from ``high``
    at x0 to ``low`` at x1) and its mono-pitch (skillion) roof slab lying on them, past the walls
    by ``overhang`` at the low eave and the two sides."""
    slope = (high - low) / (x1 - x0)
    walls = _hull([[x, 0.0, z] for x in (x0, x1) for z in (z0, z1)]
                  + [[x, high - slope * (x - x0), z] for x in (x0, x1) for z in (z0, z1)])
    xe = x1 + overhang
    roof = _hull([[x, high - slope * (x - x0) + dy, z] for x in (x0, xe) for z in (z0 - overhang, z1 + overhang)
                  for dy in (0.0, thickness)])
    return walls, roof


@RECIPES.register("house_with_annex")
def house_with_annex(width=1.1, depth=0.8, floors=2, storey=0.33, roof_height=0.34, overhang=0.05,
                     annex_width=0.55, annex_depth=0.6, annex_high=0.42, annex_low=0.26, window=(0.12, 0.16),
                     spacing=0.27, sill=0.08, door=(0.15, 0.25)):
    """A two-storey house under a gable roof with a one-storey lean-to annex against its right
    gable wall under a mono-pitch (skillion) roof, which the buildings generator has no part for:
    boxes and convex hulls, glass panes standing proud of the walls, a door in the annex front."""
    h = floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    az = 0.5 * annex_depth
    annex, annex_roof = _lean_to(hx - 0.01, hx + annex_width, -az, az, annex_low, annex_high, overhang)
    walls = [_box([-hx, 0, -hz], [hx, h, hz]), annex]
    roofs = [_gable_roof(-hx, hx, -hz, hz, h, roof_height, overhang), annex_roof]
    panes = []
    panes += _facade_openings([-hx, 0, hz], [hx, 0, hz], [0, 0, 1], floors, storey, window, spacing, sill)
    panes += _facade_openings([hx, 0, -hz], [-hx, 0, -hz], [0, 0, -1], floors, storey, window, spacing, sill)
    panes += _facade_openings([-hx, 0, -hz], [-hx, 0, hz], [-1, 0, 0], floors, storey, window, spacing, sill)
    panes += _facade_openings([hx + annex_width, 0, az], [hx + annex_width, 0, -az], [1, 0, 0], 1, storey, window,
                              spacing, sill)
    doors = _door([hx + 0.5 * annex_width, 0.0, az], door)
    return _centred(walls, roofs, panes, doors)


house_with_annex.semantic_labels = BUILDING_LABELS


@RECIPES.register("t_house")
def t_house(width=1.5, depth=0.6, floors=2, storey=0.32, roof_height=0.3, wing_width=0.55, wing_depth=0.55,
            wing_floors=2, wing_roof=0.24, overhang=0.04, window=(0.12, 0.16), spacing=0.26, sill=0.08,
            door=(0.15, 0.25)):
    """A T-shaped house: a long main block under a gable roof along x and a wing coming forward from
    the middle of its front under a lower gable along z, so the ridges cross (boxes and convex
    hulls; glass panes standing proud of the walls, a door in the wing's front)."""
    h, hw = floors * storey, wing_floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    wx = 0.5 * wing_width
    walls = [_box([-hx, 0, -hz], [hx, h, hz]), _box([-wx, 0, hz - 0.01], [wx, hw, hz + wing_depth])]
    roofs = [_gable_roof(-hx, hx, -hz, hz, h, roof_height, overhang),
             _gable_roof(-wx, wx, hz - 0.01, hz + wing_depth, hw, wing_roof, overhang, ridge_along_z=True)]
    panes = []
    for a, b in (([-hx, 0, hz], [-wx, 0, hz]), ([wx, 0, hz], [hx, 0, hz])):
        panes += _facade_openings(a, b, [0, 0, 1], floors, storey, window, spacing, sill)
    panes += _facade_openings([hx, 0, -hz], [-hx, 0, -hz], [0, 0, -1], floors, storey, window, spacing, sill)
    for sign in (-1, 1):
        panes += _facade_openings([sign * hx, 0, -sign * hz], [sign * hx, 0, sign * hz], [sign, 0, 0], floors,
                                  storey, window, spacing, sill)
        panes += _facade_openings([sign * wx, 0, hz], [sign * wx, 0, hz + wing_depth], [sign, 0, 0], wing_floors,
                                  storey, window, spacing, sill)
    front = hz + wing_depth
    panes += _facade_openings([-wx, 0, front], [wx, 0, front], [0, 0, 1], wing_floors, storey, window, spacing,
                              sill, skip=lambda a: abs(a - wx) < 0.5 * spacing)
    doors = _door([0.0, 0.0, front], door)
    return _centred(walls, roofs, panes, doors)


t_house.semantic_labels = BUILDING_LABELS
