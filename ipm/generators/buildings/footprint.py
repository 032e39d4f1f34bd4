"""The body over the footprint: the main wing's core block, the cornice round its top and the
balconies on the entrance facade; the wings, each with its walls, facades, cornice and roof."""
from __future__ import annotations

import jax.numpy as jnp

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


def wing_frames(p) -> list[tuple[int, object, object, object, object]]:
    """Each wing as (number, present, frame, side, half width): ``frame(u, v, y)`` maps the wing's
    own coordinates to the object's (``u`` out from the main wing's middle across the side it
    stands on, ``side`` the distance from that middle to the side; ``v`` across it, centred).
    Wings 1 and 2 stand on the back: wing 1 flush with the right end (L), in the middle (T) or
    flush with the left end (U), wing 2 flush with the right end (U); wing 3 on the right end."""
    hx, hz = 0.5 * p("width"), 0.5 * p("depth")
    plan = p("template")
    out = []
    for k in WINGS:
        a = 0.5 * p(f"wing{k}_width")
        if k == 3:
            centre, side, present = p("wing3_shift"), hx, p("annex") == 1
        else:
            anchor = (jnp.where(plan == L_PLAN, hx - a, jnp.where(plan == T_PLAN, 0.0, -hx + a)) if k == 1 else hx - a)
            centre, side = anchor + p(f"wing{k}_shift"), hz
            present = plan >= L_PLAN if k == 1 else plan == U_PLAN

        def frame(u, v, y, k=k, centre=centre):
            u, v, y = jnp.broadcast_arrays(u, v, y)
            return jnp.stack([u, y, centre + v] if k == 3 else [centre + v, y, -u], -1)

        out.append((k, present, frame, side, a))
    return out


def wing_solids(out: Solids, p, inset, lod: int) -> None:
    """Every wing's walls, facades (level 2 up), cornice (level 1 up) and roof, flagged by the
    template and the annex: a wing's walls run out from the side it stands on, its roof from the
    main wing's ridge line (from the side where the main roof is flat), its inner end gabled, so
    that roofs of one pitch meet as a straight skeleton's do."""
    o, co, ch = p("roof_overhang"), p("cornice_offset"), p("cornice_height")
    main_flat = p("roof_type") == FLAT
    facades = []  # (name, length, origin, windows, storeys): every wing's, built in one call
    for k, present, frame, side, a in wing_frames(p):
        top, length = wing_top(p, k), p(f"wing{k}_length")
        end = side + length
        out.boxes(WALLS, frame(side - inset, -a + inset, 0.0), frame(end - inset, a - inset, top), present)
        run = length - inset  # the end facade's wall takes the last inset
        storeys = jnp.where(present, p(f"wing{k}_floors"), 0.0)  # none where the wing is absent
        names = ("left", "right", "back") if k != 3 else ("back", "front", "right")  # facing -v, +v and +u
        facades += [(names[0], run, frame(side + 0.5 * run, -a, 0.0), p(f"wing{k}_windows"), storeys),
                    (names[1], run, frame(side + 0.5 * run, a, 0.0), p(f"wing{k}_windows"), storeys),
                    (names[2], 2 * a, frame(end, 0.0, 0.0), p(f"wing{k}_end_windows"), storeys)]
        if lod >= 1:
            out.boxes(WALLS, frame(side, -a - co, top - ch), frame(end + co, a + co, top), present)
        kind = p(f"wing{k}_roof")
        e = a + o
        flat_roof(out, frame, side, end + o, e, top, p, lod, present & (kind == FLAT), closed=False)
        pitched_roof(out, p, kind, frame, jnp.where(main_flat, side, 0.0), end + o, e, top, p(f"wing{k}_roof_height"),
                     (False, True), present & (kind != FLAT))
    if lod >= 2:
        names, lengths, origins, windows, storeys = zip(*facades)

        def wp(name):
            return jnp.stack(storeys) if name == "floors" else p(name)

        facade_boxes(out, wp, names, jnp.stack(lengths), jnp.stack(origins), jnp.stack(windows), lod, wing=True)
