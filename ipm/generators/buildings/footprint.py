"""The body over the footprint: the walls' core block, the cornice round their top and the
balconies on the entrance facade."""
from __future__ import annotations

import jax.numpy as jnp

from ipm.generators.buildings.solids import Solids
from ipm.generators.buildings.table import BALCONIES, MAX_FLOORS, RAIL, WALLS


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
