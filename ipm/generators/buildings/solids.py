"""Closed solids with corners affine in the parameters: boxes and the ten-vertex roof,
collected per part at their largest counts with a flag saying which ones a building has."""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

# corner c of a box has coordinate hi on axis k where bit k of c is set
BITS = np.array([[(c >> k) & 1 for k in range(3)] for c in range(8)], bool)
BOX_FACES = np.array([[0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5], [0, 1, 5], [0, 5, 4],
                      [2, 6, 7], [2, 7, 3], [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6]])
# a roof: the five points of its cross-section (eave, knee, ridge, knee, eave) at its first end
# (0-4) and at its other end (5-9); the bottom, the four slopes, the two ends cut into bands
ROOF_FACES = np.array([[0, 9, 4], [0, 5, 9],
                       *([k, k + 1, k + 6] for k in range(4)), *([k, k + 6, k + 5] for k in range(4)),
                       [0, 4, 3], [0, 3, 1], [1, 3, 2], [5, 8, 9], [5, 6, 8], [6, 7, 8]])
TEMPLATES = {"box": BOX_FACES, "roof": ROOF_FACES}


class Solids:
    """Collects closed solids per part at their largest count, each with a flag saying whether
    the building has it: boxes as (lo, hi) corner pairs, roofs as 10 vertices (``ROOF_FACES``). Parts and flags may
    be traced values; the topology keeps the flagged solids, the positions function all of them,
    so one compiled function serves every topology of a level of detail."""

    def __init__(self):
        self.groups: list[tuple[str, jnp.ndarray, jnp.ndarray, jnp.ndarray]] = []

    def boxes(self, part, a: jnp.ndarray, b: jnp.ndarray, valid=True) -> None:
        """Axis-aligned boxes spanned by opposite corners ``a``, ``b`` (..., 3); ``part`` and
        ``valid`` broadcast to their count."""
        a, b = jnp.broadcast_arrays(a, b)
        lead = a.shape[:-1]
        a, b = a.reshape(-1, 3), b.reshape(-1, 3)
        lo = jnp.minimum(a, b)
        hi = jnp.maximum(jnp.maximum(a, b), lo + 1e-3)  # never flat
        self.groups.append(("box", jnp.broadcast_to(part, lead).ravel(), jnp.broadcast_to(valid, lead).ravel(),
                            jnp.where(BITS[None], hi[:, None, :], lo[:, None, :])))

    def roof(self, part: int, vertices: jnp.ndarray, valid=True) -> None:
        """Roofs of ten vertices each (..., 10, 3) in ``ROOF_FACES``' order; ``valid`` broadcasts."""
        vertices = vertices.reshape(-1, 10, 3)
        lead = vertices.shape[:1]
        self.groups.append(("roof", jnp.full(lead, part), jnp.broadcast_to(valid, lead), vertices))


