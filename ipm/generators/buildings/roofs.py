"""Roofs: the nine kinds as one ten-vertex solid over a wing's eaves (a flat roof as a slab with
its parapet), and the chimney standing on the main wing's roof.

A pitched roof is its cross-section (eave, knee, ridge, knee, eave) swept along the ridge; a
hipped end pulls the knees and the ridge in from the end. The kind places the five points:
gabled, hipped and pyramidal roofs have their knees half way up straight slopes; a half-hip's
knees sit where its end's hip begins, ``1 - hip_ratio`` of the way up, so ``hip_ratio`` (the
ridge's inset, as a share of the half span) takes it from a gable (0) through half-hips to a hip
(1); a saltbox moves its ridge off the middle, a skillion to the back eave; gambrel and mansard
roofs bend their slopes at a knee (``knee_height``, ``knee_run``), the mansard on all four sides.
Every face is planar: the slopes are swept along the ridge, and each end is cut into bands whose
corners lie at one height in pairs, or on one hip plane.
"""
from __future__ import annotations

import jax.numpy as jnp

from ipm.generators.buildings.solids import Solids
from ipm.generators.buildings.table import (FLAT, GAMBREL, HALF_HIP, HIP, MANSARD, PYRAMID, RAIL, ROOF, SALTBOX,
                                            SKILLION)

MIN_RIDGE = 0.02
"""Least ridge left between two hipped ends (a pyramid's ridge shrinks to it)."""


def pitched_roof(out: Solids, p, kind, world, u0, u1, e, top, h, hips: tuple[bool, bool], valid) -> None:
    """A pitched roof of ``kind`` from ``u0`` to ``u1`` along its ridge, ``e`` to either side of it,
    its eaves at ``top`` and its ridge ``h`` above them (each a value, or one per wing);
    ``world(u, v, y)``: the wing's frame; ``hips``: whether each end may be hipped (a wing's end in
    the main wing stays gabled)."""
    i, kr, kh = p("hip_ratio"), p("knee_run"), p("knee_height")
    v_ridge = jnp.where(kind == SALTBOX, p("ridge_offset") * e, jnp.where(kind == SKILLION, -e, 0.0))
    share = jnp.where(kind == HALF_HIP, 1.0 - i, 0.5)  # how far up the straight slope the knee is
    bent = (kind == GAMBREL) | (kind == MANSARD)
    v_left = jnp.where(bent, -e * (1.0 - kr), -e + share * (v_ridge + e))
    v_right = jnp.where(bent, e * (1.0 - kr), e + share * (v_ridge - e))
    y_knee = top + jnp.where(bent, kh, share) * h
    most = (0.5 if all(hips) else 1.0) * (u1 - u0 - MIN_RIDGE)
    d_ridge = jnp.where((kind == HIP) | (kind == HALF_HIP), i * e,
                        jnp.where(kind == PYRAMID, most, jnp.where(kind == MANSARD, (kr + i * (1.0 - kr)) * e, 0.0)))
    d_ridge = jnp.minimum(d_ridge, most)
    d_knee = jnp.where((kind == HIP) | (kind == PYRAMID), 0.5 * d_ridge,
                       jnp.where(kind == MANSARD, jnp.minimum(kr * e, d_ridge), 0.0))
    profile = ((-e, top, 0.0), (v_left, y_knee, d_knee), (v_ridge, top + h, d_ridge), (v_right, y_knee, d_knee),
               (e, top, 0.0))
    ends = ((u0, 1.0 if hips[0] else 0.0), (u1, -1.0 if hips[1] else 0.0))
    out.roof(ROOF, jnp.stack([world(u + inward * d, v, y) for u, inward in ends for v, y, d in profile], -2), valid)


def flat_roof(out: Solids, world, u0, u1, e, top, p, lod: int, valid, closed: bool = True) -> None:
    """A flat roof's slab over ``u0``-``u1`` by ``-e``-``e`` at ``top`` and, level 2 up, its parapet
    along the far end and both sides (and the near end where ``closed``)."""
    rt = p("roof_thickness")
    out.boxes(ROOF, world(u0, -e, top), world(u1, e, top + rt), valid)
    if lod >= 2:
        r, ph = top + rt, top + rt + p("parapet_height")
        out.boxes(ROOF, world(u0, e - RAIL, r), world(u1, e, ph), valid)
        out.boxes(ROOF, world(u0, -e, r), world(u1, -e + RAIL, ph), valid)
        out.boxes(ROOF, world(u1 - RAIL, -e + RAIL, r), world(u1, e - RAIL, ph), valid)
        if closed:
            out.boxes(ROOF, world(u0, -e + RAIL, r), world(u0 + RAIL, e - RAIL, ph), valid)


def main_frame(u, v, y):
    """The main wing's roof frame: along x, across z."""
    return jnp.stack(jnp.broadcast_arrays(u, y, v), -1)


def roof_solids(out: Solids, p, top, lod: int) -> None:
    """The main wing's roof of walls ``top`` high (``p``: a parameter's value by name): every
    kind's solids, flagged by ``roof_type``; and its chimney."""
    w, d = p("width"), p("depth")
    roof_type = p("roof_type")
    flat = roof_type == FLAT
    o = p("roof_overhang")
    ex, ez = 0.5 * w + o, 0.5 * d + o
    flat_roof(out, main_frame, -ex, ex, ez, top, p, lod, flat)
    pitched_roof(out, p, roof_type, main_frame, -ex, ex, ez, top, p("roof_height"), (True, True), ~flat)
    if lod >= 1:
        cx, cz, cs = p("chimney_x") * w, p("chimney_z") * d, 0.5 * p("chimney_size")
        peak = top + jnp.where(flat, p("roof_thickness"), p("roof_height")) + p("chimney_height")
        out.boxes(ROOF, jnp.stack([cx - cs, top, cz - cs]), jnp.stack([cx + cs, peak, cz + cs]), p("chimney") == 1)
