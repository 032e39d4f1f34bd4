"""Building blocks shared by generators: splines, surfaces of revolution, swept tubes.

Topology helpers are numpy (computed once per level of detail); position helpers are
pure ``jax.numpy`` so that generators stay differentiable end to end.
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def catmull_rom_matrix(n_ctrl: int, n_samples: int) -> np.ndarray:
    """Weights (n_samples, n_ctrl) of a clamped uniform Catmull-Rom spline sampled at equal steps.

    The spline passes through every control point; samples = W @ controls is linear, hence
    trivially differentiable and cheap.
    """
    t = np.linspace(0.0, 1.0, n_samples) * (n_ctrl - 1)
    seg = np.minimum(np.floor(t).astype(int), n_ctrl - 2)
    s = t - seg
    w = np.zeros((n_samples, n_ctrl))
    basis = np.stack([
        -0.5 * s**3 + s**2 - 0.5 * s,
        1.5 * s**3 - 2.5 * s**2 + 1.0,
        -1.5 * s**3 + 2.0 * s**2 + 0.5 * s,
        0.5 * s**3 - 0.5 * s**2,
    ], axis=1)
    for j in range(4):
        idx = np.clip(seg + j - 1, 0, n_ctrl - 1)
        np.add.at(w, (np.arange(n_samples), idx), basis[:, j])
    return w


def catmull_rom_at(ctrl: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
    """Evaluate the clamped Catmull-Rom spline through ``ctrl`` (n,) at traced ``t`` in [0, 1]."""
    n = ctrl.shape[0]
    tt = jnp.clip(t, 0.0, 1.0) * (n - 1)
    seg = jnp.clip(jnp.floor(tt), 0, n - 2).astype(jnp.int32)
    s = tt - seg
    p = [ctrl[jnp.clip(seg + j - 1, 0, n - 1)] for j in range(4)]
    return (p[0] * (-0.5 * s**3 + s**2 - 0.5 * s) + p[1] * (1.5 * s**3 - 2.5 * s**2 + 1.0)
            + p[2] * (-1.5 * s**3 + 2.0 * s**2 + 0.5 * s) + p[3] * (0.5 * s**3 - 0.5 * s**2))


def _grid_quads(rows: np.ndarray) -> np.ndarray:
    """Triangles joining consecutive rows of vertex indices, each row a closed loop."""
    tris = []
    for a, b in zip(rows[:-1], rows[1:]):
        a1, b1 = np.roll(a, -1), np.roll(b, -1)
        tris.append(np.stack([a, b, b1], 1))
        tris.append(np.stack([a, b1, a1], 1))
    return np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)


def closed_sweep_faces(n_rows: int, n_ring: int, offset: int = 0) -> np.ndarray:
    """Faces of a closed surface: ``n_rows`` rings of ``n_ring`` vertices between two poles.

    Vertex layout (from ``offset``): pole A, then the rings row by row, then pole B. The
    result is watertight (every edge in exactly two triangles). Orientation follows the
    ring order; callers check it against the signed volume once.
    """
    rows = offset + 1 + np.arange(n_rows * n_ring).reshape(n_rows, n_ring)
    pole_a, pole_b = offset, offset + 1 + n_rows * n_ring
    first, last = rows[0], rows[-1]
    fan_a = np.stack([np.full(n_ring, pole_a), first, np.roll(first, -1)], 1)
    fan_b = np.stack([np.full(n_ring, pole_b), np.roll(last, -1), last], 1)
    return np.concatenate([fan_a, _grid_quads(rows), fan_b]).astype(np.int64)


def revolve(radius: jnp.ndarray, height: jnp.ndarray, n_ring: int) -> jnp.ndarray:
    """Rings of a surface of revolution about +y: profile (radius, height) (K,) -> (K * n_ring, 3)."""
    theta = jnp.asarray(2 * np.pi * np.arange(n_ring) / n_ring, jnp.float32)
    x = radius[:, None] * jnp.cos(theta)[None, :]
    z = -radius[:, None] * jnp.sin(theta)[None, :]
    y = jnp.broadcast_to(height[:, None], x.shape)
    return jnp.stack([x, y, z], -1).reshape(-1, 3)


def sweep_tube(path: jnp.ndarray, radius: jnp.ndarray, n_ring: int, binormal=(0.0, 0.0, 1.0)) -> jnp.ndarray:
    """Rings of a tube swept along a planar ``path`` (S, 3) with per-sample ``radius`` (S,).

    The path lies in the plane orthogonal to ``binormal``; each ring is a circle in the plane
    spanned by the in-plane normal and the binormal. Returns (S * n_ring, 3).
    """
    b = jnp.asarray(binormal, jnp.float32)
    d = jnp.concatenate([path[1:2] - path[0:1], path[2:] - path[:-2], path[-1:] - path[-2:-1]])
    t = d / jnp.sqrt(jnp.sum(d * d, -1, keepdims=True) + 1e-12)
    n = jnp.cross(t, b)
    alpha = jnp.asarray(2 * np.pi * np.arange(n_ring) / n_ring, jnp.float32)
    offs = jnp.cos(alpha)[None, :, None] * n[:, None, :] + jnp.sin(alpha)[None, :, None] * b[None, None, :]
    return (path[:, None, :] + radius[:, None, None] * offs).reshape(-1, 3)
