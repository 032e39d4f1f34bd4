"""The body over the footprint: the main wing's core block, the cornice round its top and the
balconies on the entrance facade; the wings, each with its walls, facades, cornice and roof."""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ipm.generators.buildings.facades import facade_boxes
from ipm.generators.buildings.roofs import flat_roof, pitched_roof
from ipm.generators.buildings.solids import Solids
from ipm.generators.buildings.table import (BALCONIES, FLAT, L_PLAN, MAX_FLOORS, RAIL, T_PLAN, U_PLAN, WALLS, WINGS,
                                            wing_top)


def core_solids(out: Solids, p, top, inset) -> None:
    """The walls' block ``top`` high, ``inset`` inside the facades' planes (where the facades'
    own walls stand, level 2 up)."""
    hx, hz = 0.5 * p("width"), 0.5 * p("depth")
    out.boxes(WALLS, jnp.stack([-hx + inset, 0.0, -hz + inset]), jnp.stack([hx - inset, top, hz - inset]))


def cornice_and_balconies(out: Solids, p, top, inset, lod: int) -> None:
    """The cornice under the eaves and the balconies' slabs (level 1 up), their railings (level 3)."""
    w = p("width")
    hx, hz = 0.5 * w, 0.5 * p("depth")
    co, ch = p("cornice_offset"), p("cornice_height")
    out.boxes(WALLS, jnp.stack([-hx - co, top - ch, -hz - co]), jnp.stack([hx + co, top, hz + co]))
    f = jnp.arange(1, MAX_FLOORS, dtype=jnp.float32)[:, None]  # storeys that may have a balcony
    has = (f < p("floors")) & ((p("balconies") == 1) | ((p("balconies") == 2) & (f >= p("balcony_start"))))
    y = f * p("floor_height") + p("ground_extra")
    bw, bd = 0.5 * p("balcony_width") * w, p("balcony_depth")
    rh, zero = p("railing_height"), jnp.zeros_like(y)

    def corner(xc, yc, zc):
        return jnp.stack(jnp.broadcast_arrays(xc, yc, zc), -1)

    out.boxes(BALCONIES, corner(-bw, y - p("balcony_thickness"), hz - inset), corner(bw, y, hz + bd), has)
    if lod >= 3:
        out.boxes(BALCONIES, corner(-bw, y, hz + bd - RAIL), corner(bw, y + rh, hz + bd + zero), has)
        out.boxes(BALCONIES, corner(-bw, y, hz), corner(-bw + RAIL, y + rh, hz + bd - RAIL), has)
        out.boxes(BALCONIES, corner(bw - RAIL, y, hz), corner(bw, y + rh, hz + bd - RAIL), has)


U_AXES = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]], np.float32)
"""Each wing's ``u`` axis in the object frame: out from the back (wings 1 and 2), from the right end (3)."""
V_AXES = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], np.float32)
"""Each wing's ``v`` axis (across it): with ``u`` and up the same handedness as the main roof's frame."""
FACING = (("left", "right", "back"), ("left", "right", "back"), ("back", "front", "right"))
"""The facades of each wing facing -v, +v and +u, by the main wing's names for those directions."""


def wing_frame(p):
    """The wings' frames, one value per wing in each array: ``(present, frame, side, half width)``;
    ``frame(u, v, y)`` maps the wings' own coordinates (arrays over the wings) to the object's
    (``u`` out from the main wing's middle across the side the wing stands on, ``side`` the
    distance from that middle to the side; ``v`` across it, centred). Wings 1 and 2 stand on the
    back: wing 1 flush with the right end (L), in the middle (T) or flush with the left end (U),
    wing 2 flush with the right end (U); wing 3 on the right end."""
    hx, hz = 0.5 * p("width"), 0.5 * p("depth")
    plan = p("template")
    a = jnp.stack([0.5 * p(f"wing{k}_width") for k in WINGS])
    anchor = jnp.stack([jnp.where(plan == L_PLAN, hx - a[0], jnp.where(plan == T_PLAN, 0.0, -hx + a[0])),
                        hx - a[1], jnp.zeros_like(hx)])
    centre = anchor + jnp.stack([p(f"wing{k}_shift") for k in WINGS])
    side = jnp.stack([hz, hz, hx])
    present = jnp.stack([plan >= L_PLAN, plan == U_PLAN, p("annex") == 1])
    origin = centre[:, None] * V_AXES  # the wing's middle line crosses the main wing's middle

    def frame(u, v, y):
        u, v, y = jnp.broadcast_arrays(u, v, y)
        return origin + u[:, None] * U_AXES + v[:, None] * V_AXES + y[:, None] * np.float32([0.0, 1.0, 0.0])

    return present, frame, side, a


def wing_solids(out: Solids, p, inset, lod: int) -> None:
    """Every wing's walls, facades (level 2 up), cornice (level 1 up) and roof, flagged by the
    template and the annex, each kind of solid for the three wings in one set of arrays: a wing's
    walls run out from the side it stands on, its roof from the main wing's ridge line (from the
    side where the main roof is flat), its inner end gabled, so that roofs of one pitch meet as a
    straight skeleton's do."""
    o, co, ch = p("roof_overhang"), p("cornice_offset"), p("cornice_height")
    present, frame, side, a = wing_frame(p)
    top = jnp.stack([wing_top(p, k) for k in WINGS])
    length = jnp.stack([p(f"wing{k}_length") for k in WINGS])
    end = side + length
    out.boxes(WALLS, frame(side - inset, -a + inset, 0.0), frame(end - inset, a - inset, top), present)
    if lod >= 1:
        out.boxes(WALLS, frame(side, -a - co, top - ch), frame(end + co, a + co, top), present)
    kind = jnp.stack([p(f"wing{k}_roof") for k in WINGS])
    e = a + o
    flat_roof(out, frame, side, end + o, e, top, p, lod, present & (kind == FLAT), closed=False)
    start = jnp.where(p("roof_type") == FLAT, side, 0.0)
    pitched_roof(out, p, kind, frame, start, end + o, e, top, jnp.stack([p(f"wing{k}_roof_height") for k in WINGS]),
                 (False, True), present & (kind != FLAT))
    if lod >= 2:
        run = length - inset  # the end facade's wall takes the last inset
        storeys = jnp.where(present, jnp.stack([p(f"wing{k}_floors") for k in WINGS]), 0.0)  # none where absent

        def wp(name):
            return jnp.repeat(storeys, 3) if name == "floors" else p(name)

        origins = jnp.stack([frame(side + 0.5 * run, -a, 0.0), frame(side + 0.5 * run, a, 0.0), frame(end, 0.0, 0.0)], 1)
        windows = jnp.stack([p(f"wing{k}_{n}") for k in WINGS for n in ("windows", "windows", "end_windows")])
        facade_boxes(out, wp, sum(FACING, ()), jnp.stack([run, run, 2 * a], 1).reshape(-1), origins.reshape(-1, 3),
                     windows, lod, wing=True)
