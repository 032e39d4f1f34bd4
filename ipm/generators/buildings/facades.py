"""Facades and openings: each facade's walls, windows, glass, frames and mullions on every storey,
and the entrances with their steps and canopies."""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ipm.generators.buildings.solids import Solids
from ipm.generators.buildings.table import (DOOR, FRAMES, GLASS, MAX_ENTRANCES, MAX_FLOORS, MAX_STEPS, MAX_WINDOWS,
                                            MIN_PIER, WALLS, WINDOWS)

# facades: along-facade direction and outward normal (the footprint's +z side has the entrances)
FACADES = {"front": ((1, 0, 0), (0, 0, 1)), "back": ((-1, 0, 0), (0, 0, -1)),
            "right": ((0, 0, -1), (1, 0, 0)), "left": ((0, 0, 1), (-1, 0, 0))}


def door_slots(n, n_doors, slots: int) -> jnp.ndarray:
    """Which of ``n`` evenly spaced slots (of ``slots`` at most) hold the ``n_doors`` doors,
    spread evenly: slot ``round((k + 1/2) n / n_doors - 1/2)`` for door k."""
    k = jnp.arange(MAX_ENTRANCES, dtype=jnp.float32)[:, None]
    at = jnp.round((k + 0.5) * n / jnp.maximum(n_doors, 1.0) - 0.5)
    j = jnp.arange(slots, dtype=jnp.float32)[None, :]
    return jnp.any((at == j) & (k < n_doors), axis=0)


def facade_boxes(s: Solids, p, facade, length, origin, n_windows, lod: int, wing: bool = False) -> None:
    """Walls, openings, glass, frames and mullions of one facade, every floor at once, or of
    several (``facade`` a tuple of names; ``length``, ``origin``, ``n_windows`` and ``p("floors")``
    one per facade) in one set of arrays, so that the compiled program does not grow with them.

    Local coordinates: ``a`` along the facade (centred), ``y`` up, ``d`` into the building from
    the wall plane. Arrays run over (facades, floors, slots) at their largest counts; the main
    wing's front facade's ground floor has the entrances among its windows, and steps and canopies
    before them (a ``wing``'s facades face the way ``facade`` names, with windows only, at their
    full scale).
    """
    names = (facade,) if isinstance(facade, str) else tuple(facade)
    along, normal = (np.asarray([FACADES[n][k] for n in names], np.float32)[:, None, None, :] for k in (0, 1))
    up = np.array([0.0, 1.0, 0.0], np.float32)
    front = names == ("front",) and not wing
    origin = jnp.reshape(origin, (-1, 1, 1, 3))

    def col(v):  # one value per facade, against (facades, floors, slots)
        return jnp.reshape(v, (-1, 1, 1))

    def put(part, a0, a1, y0, y1, d0, d1, valid):
        def world(a, y, d):
            a, y, d = jnp.broadcast_arrays(a, y, d)
            return origin + a[..., None] * along + y[..., None] * up - d[..., None] * normal

        s.boxes(part, world(a0, y0, d0), world(a1, y1, d1), valid)

    length = col(length)
    inset, half = p("window_inset"), 0.5 * length
    fh, g = p("floor_height"), p("ground_extra")
    n_slots = MAX_WINDOWS + (MAX_ENTRANCES if front else 0)
    f = jnp.arange(MAX_FLOORS, dtype=jnp.float32)[None, :, None]  # (1, F, 1)
    j = jnp.arange(n_slots, dtype=jnp.float32)[None, None, :]  # (1, 1, S)
    ground = f == 0
    storey = f < col(p("floors"))
    n_doors = p("entrances") if front else 0.0
    steps = p("steps") if front else 0.0
    n = jnp.where(ground, col(n_windows) + n_doors, col(n_windows))  # openings per floor (W, F, 1)
    is_door = ground & (door_slots(n_windows + n_doors, n_doors, n_slots) if front else False)  # (W, F, S)
    opening = storey & (j < n)
    y_base = jnp.where(ground, 0.0, f * fh + g)
    y_top = (f + 1) * fh + g
    height = y_top - y_base
    margin = jnp.minimum(p("window_margin"), half - 0.5 * MIN_PIER)
    slot = (length - 2 * margin) / jnp.maximum(n, 1.0)
    centre = -half + margin + (j + 0.5) * slot
    scale = col(jnp.stack([p("side_window_scale") if n in ("left", "right") and not wing else jnp.float32(1.0)
                           for n in names]))
    scale = jnp.where(ground, scale * p("ground_window_scale"), scale)
    w = jnp.where(is_door, jnp.minimum(p("door_width"), slot - MIN_PIER),
                  jnp.minimum(p("window_width") * scale, slot - MIN_PIER))
    sill = p("window_sill")
    win_h = jnp.where(ground, p("ground_window_height"), p("window_height"))
    door_y0 = steps * p("step_height")
    y0 = jnp.where(is_door, door_y0, y_base + sill)
    y1 = jnp.where(is_door, door_y0 + jnp.minimum(p("door_height"), height - door_y0 - MIN_PIER),
                   y_base + sill + jnp.minimum(win_h, height - sill - MIN_PIER))
    a0, a1 = centre - 0.5 * w, centre + 0.5 * w
    # piers between openings (full storey; pier k ends at the facade's edge when k = n), then the
    # wall below and above each opening
    k = jnp.arange(n_slots + 1, dtype=jnp.float32)[None, None, :]
    edge = jnp.broadcast_to(half, (len(names), MAX_FLOORS, 1))
    pier_end = jnp.where(k == n, half, jnp.concatenate([a0, edge], -1))
    put(WALLS, jnp.concatenate([-edge, a1], -1), pier_end, y_base, y_top, 0.0, inset, storey & (k <= n))
    put(WALLS, a0, a1, y_base, y0, 0.0, inset, opening & (~is_door | (steps > 0)))
    put(WALLS, a0, a1, y1, y_top, 0.0, inset, opening)
    # the pane: at level 2 (no frames) as much of it as level 3's frames leave visible, so the
    # window masks of the two levels agree and the pane's edges lie inside the core wall's face
    # rather than along the reveal's (coplanar edges bias the silhouette renderer's gradients)
    fw = jnp.minimum(p("frame_width"), 0.25 * jnp.minimum(w, y1 - y0)) if lod == 2 else 0.0
    put(jnp.where(is_door, DOOR, WINDOWS), a0 + fw, a1 - fw, jnp.where(is_door, y0, y0 + fw), y1 - fw,
        inset - GLASS, inset, opening)
    win = opening & ~is_door
    if lod >= 3:
        fw, fd = p("frame_width"), p("frame_depth")
        back = inset - GLASS
        # frames wrap the opening's edges, so no frame face lies in a wall face
        yf = jnp.where(is_door, y0, y0 - fw)  # a door's frame stands on its threshold
        put(FRAMES, a0 - fw, a0 + fw, yf, y1 + fw, -fd, back, opening)
        put(FRAMES, a1 - fw, a1 + fw, yf, y1 + fw, -fd, back, opening)
        put(FRAMES, a0 - fw, a1 + fw, y1 - fw, y1 + fw, -fd, back, opening)
        put(FRAMES, a0 - fw, a1 + fw, y0 - fw, y0 + fw, -fd, back, win)
        mw, mid_a, mid_y = 0.5 * p("mullion_width"), 0.5 * (a0 + a1), 0.5 * (y0 + y1)
        put(FRAMES, mid_a - mw, mid_a + mw, y0, y1, back - 2 * GLASS, back, win & (p("window_split") >= 1))
        put(FRAMES, a0, a1, mid_y - mw, mid_y + mw, back - 2 * GLASS, back, win & (p("window_split") >= 2))
    if front:
        door = is_door[0, 0] & opening[0, 0]
        dl, dr, dt = a0[0, 0], a1[0, 0], y1[0, 0]
        if lod >= 2:
            m = jnp.arange(MAX_STEPS, dtype=jnp.float32)[:, None]  # the lowest step reaches farthest out
            put(WALLS, dl - 0.02, dr + 0.02, 0.0, door_y0 - m * p("step_height"), -(m + 1) * p("step_depth"),
                inset, door & (m < steps))
        if lod >= 3:
            over = p("canopy_overhang")
            put(WALLS, dl - over, dr + over, dt + 0.02, dt + 0.035, -p("canopy_depth"), 0.0, door)


