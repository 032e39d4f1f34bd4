"""Buildings of the shapes real ones take and the buildings generator does not make, for the test
split's out-of-family cases (a U-shaped block round a courtyard, a cross-gabled house, a barn under
a gambrel roof and a tower under a pyramidal roof) and the dev split's (a house under a mansard
roof, a saltbox house, a gabled farmhouse whose wing makes an L, a pavilion on a plinth under a
pyramidal roof). Independent code as in
:mod:`datasets_synthetic.recipes` (boxes and convex hulls, no generator code), registered in its
``RECIPES``; each part closed, wound outwards; labels wall, window, roof, door."""
from __future__ import annotations

import numpy as np

from datasets_synthetic.more_recipes import _centred
from datasets_synthetic.recipes import RECIPES, _box, _door, _facade_openings, _gable_roof, _hip_roof, _hull
from ipm.io.semantic import BUILDING_LABELS


def _box_facades(hx, hz, floors, storey, window, spacing, sill) -> list:
    """Panes on the four walls of the block [-hx, hx] x [-hz, hz], every storey, the front's
    (+z) middle left for the door."""
    panes = []
    for a, b, n in (([hx, 0, -hz], [-hx, 0, -hz], [0, 0, -1]), ([-hx, 0, -hz], [-hx, 0, hz], [-1, 0, 0]),
                    ([hx, 0, hz], [hx, 0, -hz], [1, 0, 0])):
        panes += _facade_openings(a, b, n, floors, storey, window, spacing, sill)
    return panes + _facade_openings([-hx, 0, hz], [hx, 0, hz], [0, 0, 1], floors, storey, window, spacing, sill,
                                    skip=lambda a: abs(a - hx) < 0.5 * spacing)


def _flat_roof(x0, x1, z0, z1, base, slab=0.04, parapet=0.06, rail=0.02) -> list:
    """A flat roof's slab over [x0, x1] x [z0, z1] and the four parapet walls round its edge."""
    top = base + slab
    return [_box([x0, base, z0], [x1, top, z1]),
            _box([x0, top, z0], [x1, top + parapet, z0 + rail]), _box([x0, top, z1 - rail], [x1, top + parapet, z1]),
            _box([x0, top, z0 + rail], [x0 + rail, top + parapet, z1 - rail]),
            _box([x1 - rail, top, z0 + rail], [x1, top + parapet, z1 - rail])]


@RECIPES.register("courtyard_block")
def courtyard_block(width=1.8, depth=1.3, wing=0.45, floors=3, storey=0.3, window=(0.11, 0.15), spacing=0.24,
                    sill=0.08, door=(0.16, 0.25)):
    """A U-shaped block of flats round a courtyard open to the front: a back wing along x and two
    side wings coming forward from its ends, all ``floors`` storeys under one flat roof with a
    parapet; windows on every outer and courtyard wall, the door in the courtyard's back."""
    h = floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    back_z = -hz + wing  # the back wing's courtyard face
    walls = [_box([-hx, 0, -hz], [hx, h, back_z]), _box([-hx, 0, back_z - 0.01], [-hx + wing, h, hz]),
             _box([hx - wing, 0, back_z - 0.01], [hx, h, hz])]
    roofs = (_flat_roof(-hx, hx, -hz, back_z, h) + _flat_roof(-hx, -hx + wing, back_z, hz, h)
             + _flat_roof(hx - wing, hx, back_z, hz, h))
    panes = []
    walls_out = (([hx, 0, -hz], [-hx, 0, -hz], [0, 0, -1]), ([-hx, 0, -hz], [-hx, 0, hz], [-1, 0, 0]),
                 ([hx, 0, hz], [hx, 0, -hz], [1, 0, 0]), ([-hx, 0, hz], [-hx + wing, 0, hz], [0, 0, 1]),
                 ([hx - wing, 0, hz], [hx, 0, hz], [0, 0, 1]),
                 ([-hx + wing, 0, hz], [-hx + wing, 0, back_z], [1, 0, 0]),
                 ([hx - wing, 0, back_z], [hx - wing, 0, hz], [-1, 0, 0]))
    for a, b, n in walls_out:
        panes += _facade_openings(a, b, n, floors, storey, window, spacing, sill)
    inner = 2 * (hx - wing)
    panes += _facade_openings([-hx + wing, 0, back_z], [hx - wing, 0, back_z], [0, 0, 1], floors, storey, window,
                              spacing, sill, skip=lambda a: abs(a - 0.5 * inner) < 0.5 * spacing)
    doors = _door([0.0, 0.0, back_z], door)
    return _centred(walls, roofs, panes, doors)


courtyard_block.semantic_labels = BUILDING_LABELS


@RECIPES.register("cross_gabled_house")
def cross_gabled_house(width=1.1, depth=1.0, floors=2, storey=0.32, roof_height=0.38, overhang=0.05,
                       window=(0.12, 0.16), spacing=0.28, sill=0.08, door=(0.15, 0.25)):
    """A near-square two-storey house under two gable roofs of one height crossing at right angles
    (four gables, one per wall): the union of a gable along x and one along z."""
    h = floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    walls = [_box([-hx, 0, -hz], [hx, h, hz])]
    roofs = [_gable_roof(-hx, hx, -hz, hz, h, roof_height, overhang),
             _gable_roof(-hx, hx, -hz, hz, h, roof_height, overhang, ridge_along_z=True)]
    panes = _box_facades(hx, hz, floors, storey, window, spacing, sill)
    return _centred(walls, roofs, panes, _door([0.0, 0.0, hz], door))


cross_gabled_house.semantic_labels = BUILDING_LABELS


@RECIPES.register("gambrel_barn")
def gambrel_barn(width=0.9, length=1.7, wall_height=0.38, knee=0.3, knee_in=0.14, ridge=0.22, overhang=0.04,
                 window=(0.1, 0.12), spacing=0.34, sill=0.14, door=(0.36, 0.42)):
    """A barn along z under a gambrel roof: each side a steep lower slope up to the knee
    (``knee`` higher, ``knee_in`` inwards) and a shallow upper one to the ridge (``ridge`` higher
    again); a wide door in the front gable, small windows along the sides."""
    hx, hz = 0.5 * width, 0.5 * length
    walls = [_box([-hx, 0, -hz], [hx, wall_height, hz])]
    ex, z0, z1 = hx + overhang, -hz - overhang, hz + overhang
    section = [(-ex, wall_height), (-hx + knee_in, wall_height + knee), (0.0, wall_height + knee + ridge),
               (hx - knee_in, wall_height + knee), (ex, wall_height)]
    roofs = [_hull([[x, y, z] for x, y in section for z in (z0, z1)])]
    panes = []
    for sign in (-1, 1):
        panes += _facade_openings([sign * hx, 0, -sign * hz], [sign * hx, 0, sign * hz], [sign, 0, 0], 1, 0.3,
                                  window, spacing, sill)
    panes += _facade_openings([hx, 0, -hz], [-hx, 0, -hz], [0, 0, -1], 1, 0.3, window, 0.3, sill)
    doors = _door([0.0, 0.0, hz], door)
    return _centred(walls, roofs, panes, doors)


gambrel_barn.semantic_labels = BUILDING_LABELS


@RECIPES.register("pyramid_tower")
def pyramid_tower(side=0.7, floors=5, storey=0.3, roof_height=0.5, overhang=0.05, window=(0.11, 0.16),
                  spacing=0.22, sill=0.08, door=(0.15, 0.25)):
    """A square tower of ``floors`` storeys under a pyramidal roof (four triangular slopes to one
    apex): windows on every storey of every side, a door in the front."""
    h, s = floors * storey, 0.5 * side
    walls = [_box([-s, 0, -s], [s, h, s])]
    e = s + overhang
    roofs = [_hull([[x, h, z] for x in (-e, e) for z in (-e, e)] + [[0.0, h + roof_height, 0.0]])]
    panes = _box_facades(s, s, floors, storey, window, spacing, sill)
    return _centred(walls, roofs, panes, _door([0.0, 0.0, s], door))


pyramid_tower.semantic_labels = BUILDING_LABELS


@RECIPES.register("mansard_house")
def mansard_house(width=1.3, depth=0.9, floors=2, storey=0.32, lower=0.3, lower_in=0.1, upper=0.1, overhang=0.04,
                  window=(0.12, 0.16), spacing=0.28, sill=0.08, door=(0.15, 0.25)):
    """A two-storey house under a mansard roof: on all four sides a steep lower slope (``lower``
    high, ``lower_in`` inwards) and above it a low hipped top (``upper`` high) over the smaller
    rectangle; windows on every storey, a door in the front."""
    h = floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    walls = [_box([-hx, 0, -hz], [hx, h, hz])]
    ex, ez = hx + overhang, hz + overhang
    kx, kz, top = hx - lower_in, hz - lower_in, h + lower
    ridge = kx - kz  # the hipped top's ridge along x, its four slopes of one pitch
    points = [[x, h, z] for x in (-ex, ex) for z in (-ez, ez)] + [[x, top, z] for x in (-kx, kx) for z in (-kz, kz)]
    points += [[-ridge, top + upper, 0.0], [ridge, top + upper, 0.0]]
    roofs = [_hull(points)]
    panes = _box_facades(hx, hz, floors, storey, window, spacing, sill)
    return _centred(walls, roofs, panes, _door([0.0, 0.0, hz], door))


mansard_house.semantic_labels = BUILDING_LABELS


@RECIPES.register("saltbox_house")
def saltbox_house(width=1.2, depth=0.95, front_floors=2, storey=0.3, back_eave=0.32, ridge_at=0.35, ridge=0.28,
                  overhang=0.04, window=(0.12, 0.16), spacing=0.27, sill=0.08, door=(0.15, 0.25)):
    """A saltbox house: two storeys at the front (+z), one at the back, under an asymmetric gable
    along x whose ridge stands ``ridge_at`` of the depth from the front and whose long rear slope
    comes down to the back wall's lower eave; windows on the front's storeys, the back's and the
    ends' ground floor, a door in the front."""
    front = front_floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    zr = hz - ridge_at * depth
    apex = front + ridge
    walls = [_hull([[x, 0.0, z] for x in (-hx, hx) for z in (-hz, hz)]
                   + [[x, y, z] for x in (-hx, hx) for y, z in ((front, hz), (apex - 0.02, zr), (back_eave, -hz))])]
    ex = hx + overhang
    fz, bz = hz + overhang, -hz - overhang
    fy = front - overhang * ridge / (hz - zr)
    by = back_eave - overhang * (apex - back_eave) / (zr + hz)
    section = [(fz, fy), (zr, apex), (bz, by)]
    roofs = [_hull([[x, y, z] for z, y in section for x in (-ex, ex)]
                   + [[x, y + 0.03, z] for z, y in section for x in (-ex, ex)])]
    panes = _facade_openings([hx, 0, -hz], [-hx, 0, -hz], [0, 0, -1], 1, storey, window, spacing, sill)
    for sign in (-1, 1):
        panes += _facade_openings([sign * hx, 0, -sign * hz], [sign * hx, 0, sign * hz], [sign, 0, 0], 1, storey,
                                  window, spacing, sill)
    panes += _facade_openings([-hx, 0, hz], [hx, 0, hz], [0, 0, 1], front_floors, storey, window, spacing, sill,
                              skip=lambda a: abs(a - hx) < 0.5 * spacing)
    return _centred(walls, roofs, panes, _door([0.0, 0.0, hz], door))


saltbox_house.semantic_labels = BUILDING_LABELS


@RECIPES.register("l_farmhouse")
def l_farmhouse(width=1.4, depth=0.7, floors=2, storey=0.31, roof_height=0.36, wing_width=0.6, wing_depth=0.7,
                wing_storey=0.4, wing_roof=0.3, wing_at=-1, wing_side=1, overhang=0.05, window=(0.11, 0.15),
                spacing=0.26, sill=0.08, door=(0.15, 0.25)):
    """An L-shaped farmhouse: a main block under a gable roof along x and, flush with its end at
    ``wing_at`` (-1 left, +1 right), a one-storey wing ``wing_storey`` high going out from its front
    (``wing_side`` +1) or back (-1) under a lower gable along z whose ridge runs into the main roof;
    windows on every wall, a door in the wall the wing goes out from, beside the wing (at the back
    where the wing goes back) (boxes and convex hulls; no generator code)."""
    h = floors * storey
    hx, hz = 0.5 * width, 0.5 * depth
    x0, x1 = sorted((wing_at * hx, wing_at * (hx - wing_width)))
    z0, z1 = sorted((wing_side * (hz - 0.01), wing_side * (hz + wing_depth)))
    walls = [_box([-hx, 0, -hz], [hx, h, hz]), _box([x0, 0, z0], [x1, wing_storey, z1])]
    roofs = [_gable_roof(-hx, hx, -hz, hz, h, roof_height, overhang),
             _gable_roof(x0, x1, z0, z1, wing_storey, wing_roof, overhang, ridge_along_z=True)]
    sf = np.array([0.0, 0.0, wing_side])
    panes = _facade_openings([hx * -wing_side, 0, -wing_side * hz], [hx * wing_side, 0, -wing_side * hz], -sf, floors,
                             storey, window, spacing, sill)
    free = sorted((wing_at * (hx - wing_width), -wing_at * hx))
    panes += _facade_openings([free[0], 0, wing_side * hz], [free[1], 0, wing_side * hz], sf, floors, storey, window,
                              spacing, sill, skip=lambda a: abs(a - 0.5 * (free[1] - free[0])) < 0.5 * spacing)
    for sign in (-1, 1):
        panes += _facade_openings([sign * hx, 0, -sign * hz], [sign * hx, 0, sign * hz], [sign, 0, 0], floors, storey,
                                  window, spacing, sill)
        xs = x1 if sign > 0 else x0
        panes += _facade_openings([xs, 0, z0], [xs, 0, z1], [sign, 0, 0], 1, storey, window, spacing, sill)
    end = wing_side * (hz + wing_depth)
    panes += _facade_openings([x0, 0, end], [x1, 0, end], sf, 1, storey, window, spacing, sill)
    doors = _door([0.5 * (free[0] + free[1]), 0.0, wing_side * hz], door)
    return _centred(walls, roofs, panes, doors)


l_farmhouse.semantic_labels = BUILDING_LABELS


@RECIPES.register("plinth_pavilion")
def plinth_pavilion(width=1.0, depth=1.0, floors=2, storey=0.32, plinth=0.1, plinth_out=0.03, roof_height=0.5,
                    overhang=0.07, window=(0.12, 0.17), spacing=0.25, sill=0.09, door=(0.16, 0.26)):
    """A pavilion or tower: a block of ``floors`` storeys standing on a plinth ``plinth`` high that
    juts ``plinth_out`` beyond its walls, under a hip roof whose ridge shrinks to a point where the
    plan is square (a pyramidal roof); windows on every storey of every wall, a door in the front
    (boxes and convex hulls; no generator code)."""
    hx, hz, h = 0.5 * width, 0.5 * depth, plinth + floors * storey
    walls = [_box([-hx - plinth_out, 0, -hz - plinth_out], [hx + plinth_out, plinth, hz + plinth_out]),
             _box([-hx, plinth - 0.01, -hz], [hx, h, hz])]
    roofs = [_hip_roof(-hx, hx, -hz, hz, h, roof_height, overhang)]
    panes = [p.apply_translation([0.0, plinth, 0.0]) for p in _box_facades(hx, hz, floors, storey, window, spacing, sill)]
    return _centred(walls, roofs, panes, _door([0.0, plinth, hz], door))


plinth_pavilion.semantic_labels = BUILDING_LABELS
