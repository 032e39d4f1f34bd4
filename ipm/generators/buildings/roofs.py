"""Roofs: a flat roof's slab and parapet, the gable or hip prism over the eaves, and the chimney
standing on either."""
from __future__ import annotations

import jax.numpy as jnp

from ipm.generators.buildings.solids import Solids
from ipm.generators.buildings.table import FLAT, GABLE, RAIL, ROOF


def roof_solids(out: Solids, p, top, lod: int) -> None:
    """The roof of walls ``top`` high over the footprint (``p``: a parameter's value by name):
    every kind's solids, flagged by ``roof_type``."""
    w, d = p("width"), p("depth")
    roof_type = p("roof_type")
    flat = roof_type == FLAT
    o = p("roof_overhang")
    ex, ez = 0.5 * w + o, 0.5 * d + o
    rt = p("roof_thickness")
    out.boxes(ROOF, jnp.stack([-ex, top, -ez]), jnp.stack([ex, top + rt, ez]), flat)
    if lod >= 2:
        r, ph = top + rt, top + rt + p("parapet_height")
        out.boxes(ROOF, jnp.stack([-ex, r, ez - RAIL]), jnp.stack([ex, ph, ez]), flat)
        out.boxes(ROOF, jnp.stack([-ex, r, -ez]), jnp.stack([ex, ph, -ez + RAIL]), flat)
        out.boxes(ROOF, jnp.stack([ex - RAIL, r, -ez + RAIL]), jnp.stack([ex, ph, ez - RAIL]), flat)
        out.boxes(ROOF, jnp.stack([-ex, r, -ez + RAIL]), jnp.stack([-ex + RAIL, ph, ez - RAIL]), flat)
    ridge = top + p("roof_height")
    half_ridge = jnp.where(roof_type == GABLE, ex, jnp.maximum(ex - p("hip_ratio") * ez, 0.01))
    out.prism(ROOF, jnp.stack([jnp.stack([-ex, top, -ez]), jnp.stack([ex, top, -ez]),
                               jnp.stack([ex, top, ez]), jnp.stack([-ex, top, ez]),
                               jnp.stack([-half_ridge, ridge, 0.0]), jnp.stack([half_ridge, ridge, 0.0])]),
              ~flat)
    if lod >= 1:
        cx, cz, cs = p("chimney_x") * w, p("chimney_z") * d, 0.5 * p("chimney_size")
        peak = jnp.where(flat, top + rt, ridge) + p("chimney_height")
        out.boxes(ROOF, jnp.stack([cx - cs, top, cz - cs]), jnp.stack([cx + cs, peak, cz + cs]), p("chimney") == 1)
