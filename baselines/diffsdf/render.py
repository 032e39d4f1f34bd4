"""Soft silhouettes of a signed distance grid, in JAX: rays, trilinear lookup, closest approach.

The field lives on a cell-centred grid over the object box, stored in units of the box's
longest side (``L``). Rays are kept in grid-index space (``u = (x - lo) / h - 0.5``, cell
centres at integers) with their parameter ``t`` in world units, so a sample is one
multiply-add away from a trilinear lookup.

A ray's silhouette value is ``sigmoid(-f_min / w)`` where ``f_min`` is the smallest sampled
SDF value along the ray inside the box and ``w`` the edge width in SDF units. With NeuS's
logistic-CDF opacity this is exact for a ray with one dip: the log-transmittance
telescopes to ``log sigmoid(f_min / w)``. The search for the minimum carries no gradient
(``lax.fori_loop`` over samples, O(rays) memory: a coarse pass, then a fine one around its
minimum); the loss is then differentiated through one trilinear lookup per ray at the
minimising sample (the envelope theorem: the minimiser's own shift does not change the
minimum to first order), so the backward pass is cheap.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rays:
    """The pixel rays of all views that cross the box, in grid-index space (numpy)."""

    origin: np.ndarray
    """(N, 3) ray origins in grid-index coordinates."""
    direction: np.ndarray
    """(N, 3) index-space displacement per unit of world ``t``."""
    t0: np.ndarray
    """(N,) world-distance entry into the box."""
    t1: np.ndarray
    """(N,) world-distance exit from the box."""
    footprint: np.ndarray
    """(N,) width of one pixel at the box centre's depth, in units of ``L``."""
    pixel: np.ndarray
    """(N,) flat index into the (views, height, width) image stack."""
    shape: tuple
    """(views, height, width) of the image stack."""


def pixel_rays(c2w: np.ndarray, fov_x: float, width: int, height: int, lo: np.ndarray, hi: np.ndarray,
               shape: tuple, scale: float) -> Rays:
    """Rays through the pixel centres of every view, those that cross the box [lo, hi], in the
    index space of a cell-centred grid of ``shape`` over that box; ``scale`` is ``L``."""
    h = (hi - lo) / np.asarray(shape)
    f = 0.5 * width / np.tan(0.5 * fov_x)
    px, py = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d_cam = np.stack([(px - width / 2) / f, -(py - height / 2) / f, -np.ones_like(px)], -1).reshape(-1, 3)
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    centre = 0.5 * (lo + hi)
    parts = {k: [] for k in ("o", "d", "t0", "t1", "fp", "pix")}
    for v, m in enumerate(c2w):
        d = d_cam @ m[:3, :3].T
        o = np.broadcast_to(m[:3, 3], d.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            ta, tb = (lo - o) * inv, (hi - o) * inv
        tn = np.nanmax(np.minimum(ta, tb), 1)
        tf = np.nanmin(np.maximum(ta, tb), 1)
        tn = np.maximum(tn, 0.0)
        hit = tf > tn
        depth = float(-(centre - m[:3, 3]) @ m[:3, 2])
        parts["o"].append((o[hit] - lo) / h - 0.5)
        parts["d"].append(d[hit] / h)
        parts["t0"].append(tn[hit])
        parts["t1"].append(tf[hit])
        parts["fp"].append(np.full(hit.sum(), depth / f / scale))
        parts["pix"].append(v * width * height + np.flatnonzero(hit))
    cat = {k: np.concatenate(p) for k, p in parts.items()}
    return Rays(cat["o"].astype(np.float32), cat["d"].astype(np.float32), cat["t0"].astype(np.float32),
                cat["t1"].astype(np.float32), cat["fp"].astype(np.float32), cat["pix"].astype(np.int32),
                (len(c2w), height, width))


def trilinear(grid, u):
    """Trilinear value of a cell-centred ``grid`` (nx, ny, nz) at index coordinates ``u`` (N, 3),
    clamped to the outermost cell centres."""
    import jax.numpy as jnp

    grid = jnp.asarray(grid)
    n = np.asarray(grid.shape)
    u = jnp.clip(u, 0.0, (n - 1).astype(np.float32))
    i = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, (n - 2).astype(np.int32))
    w = u - i
    sx, sy = int(n[1] * n[2]), int(n[2])
    base = i[:, 0] * sx + i[:, 1] * sy + i[:, 2]
    flat = grid.reshape(-1)
    out = 0.0
    for dx in (0, 1):
        wx = w[:, 0] if dx else 1.0 - w[:, 0]
        for dy in (0, 1):
            wy = w[:, 1] if dy else 1.0 - w[:, 1]
            for dz in (0, 1):
                wz = w[:, 2] if dz else 1.0 - w[:, 2]
                out = out + wx * wy * wz * flat[base + dx * sx + dy * sy + dz]
    return out


def _argmin_along(grid, origin, direction, start, dt, jitter, n_samples: int):
    """Index of the smallest of ``n_samples`` values at ``start + (k + jitter) * dt`` per ray.

    The running minimum is one int32 per ray: the order-preserving bits of ``f + 4`` (the field
    is clipped to [-3.5, 3.5]) with the sample index in the low bits. Tracking value and index
    separately makes XLA's CPU backend recompute the gathers for each consumer (6x slower).
    """
    import jax
    import jax.numpy as jnp

    bits = max(1, (n_samples - 1).bit_length())
    low = (1 << bits) - 1

    def body(k, best):
        f = trilinear(grid, origin + (start + (k + jitter) * dt)[:, None] * direction)
        key = (jax.lax.bitcast_convert_type(jnp.clip(f, -3.5, 3.5) + 4.0, jnp.int32) & ~low) | k
        return jnp.minimum(best, key)

    best = jax.lax.fori_loop(0, n_samples, body, jnp.full(start.shape, jnp.iinfo(jnp.int32).max, jnp.int32))
    return (best & low).astype(start.dtype)


def closest_approach(grid, origin, direction, t0, t1, jitter, n_samples: int, refine: int = 0):
    """World ``t`` of the smallest sampled value along each ray; no gradient flows.

    ``n_samples`` stratified samples in [t0, t1], all shifted by the per-ray ``jitter`` in
    [0, 1); then, if ``refine``, that many more in the interval of one coarse spacing either
    side of the best coarse sample. Since a distance field changes by at most the distance
    moved, the coarse pass can only pick the wrong dip when two dips are within half a coarse
    spacing of each other in depth.
    """
    import jax
    import jax.numpy as jnp

    grid = jax.lax.stop_gradient(jnp.asarray(grid))
    dt = (t1 - t0) / n_samples
    k = _argmin_along(grid, origin, direction, t0, dt, jitter, n_samples)
    t = t0 + (k + jitter) * dt
    if not refine:
        return t
    lo = jnp.maximum(t - dt, t0)
    fine = (jnp.minimum(t + dt, t1) - lo) / refine
    k = _argmin_along(grid, origin, direction, lo, fine, jitter, refine)
    return lo + (k + jitter) * fine


def silhouettes(grid, rays, tmin, width):
    """Per-ray soft silhouette ``sigmoid(-f(t_min) / (width * footprint))``, differentiable in
    ``grid``; ``rays`` holds jax arrays (origin, direction, footprint) and ``width`` is in pixels."""
    import jax

    origin, direction, footprint = rays
    f = trilinear(grid, origin + tmin[:, None] * direction)
    return jax.nn.sigmoid(-f / (width * footprint))


def image_stack(values, pixel, shape):
    """Scatter per-ray values into a zero (views, height, width) stack."""
    import jax.numpy as jnp

    return jnp.zeros(int(np.prod(shape)), values.dtype).at[pixel].set(values).reshape(shape)


def pyramid(images, levels: int) -> list:
    """``images`` and up to ``levels - 1`` successive 2x2 box-filtered halvings (odd edges cropped)."""
    out = [images]
    for _ in range(levels - 1):
        x = out[-1]
        h, w = x.shape[-2] // 2 * 2, x.shape[-1] // 2 * 2
        if h < 2 or w < 2:
            break
        x = x[..., :h, :w]
        out.append(0.25 * (x[..., 0::2, 0::2] + x[..., 1::2, 0::2] + x[..., 0::2, 1::2] + x[..., 1::2, 1::2]))
    return out


def laplacian_energy(grid):
    """Sum of squared 7-point Laplacians (index units) over the interior cells."""
    c = grid[1:-1, 1:-1, 1:-1]
    lap = (grid[2:, 1:-1, 1:-1] + grid[:-2, 1:-1, 1:-1] + grid[1:-1, 2:, 1:-1] + grid[1:-1, :-2, 1:-1]
           + grid[1:-1, 1:-1, 2:] + grid[1:-1, 1:-1, :-2] - 6.0 * c)
    return (lap * lap).sum()
