"""Rays, the occupancy grid and volume rendering with samples only in occupied space, in JAX.

Coordinates are the unit frame of the object box: ``u = (x - lo) / L`` (``L`` the box's longest
side), so the box is [0, ext] with ext <= 1 per axis, distances ``t`` and densities are in units
of ``L``.

Empty-space skipping with static shapes: each ray is walked in fixed candidate steps ``dt``
(``n_candidates`` over the longest chord) and each candidate looked up in the occupancy bits (one
gather, no network). The batch's occupied candidates are counted in order (ray, then depth) and
a fixed budget of ``n_samples`` network samples for the whole batch is spread evenly over them
(stratified: sample ``s`` falls on the occupied candidate ``floor((s + j_s) r)``, ``r`` occupied
candidates per sample, never below ``min_ratio``), each sample covering ``r dt`` of occupied
length. Rays that meet no occupied cell cost nothing, and a ray gets samples in proportion to
its occupied length. What it saves on a CPU: the network runs ``n_samples`` times per batch
whatever the occupancy, so a step's time is fixed; as the grid empties, the same samples come
closer together (from about the whole chord over the budget at the start to ``min_ratio dt``),
i.e. a dense sampler would need ``1 / occupied share`` times as many network evaluations for the
same spacing. The candidate walk itself (rays x candidates bit lookups) is not skipped.
Compositing is per ray by a segmented scan over the flat sample list (ray ids ascending), so
the optical depth never accumulates across rays in float32.
"""
from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from baselines.diffsdf.render import pixel_rays


@dataclass(frozen=True)
class UnitRays:
    """Pixel rays that cross the object box, in the box's unit frame (numpy)."""

    origin: np.ndarray
    """(N, 3) origins, ``(x - lo) / L``."""
    direction: np.ndarray
    """(N, 3) unit directions."""
    t0: np.ndarray
    """(N,) entry into the box, units of ``L``."""
    t1: np.ndarray
    """(N,) exit from the box, units of ``L``."""
    pixel: np.ndarray
    """(N,) flat index into the (views, height, width) images."""


def unit_rays(c2w: np.ndarray, fov_x: float, width: int, height: int, lo: np.ndarray, hi: np.ndarray) -> UnitRays:
    """The rays through every pixel centre of the views that cross the box [lo, hi]
    (``baselines.diffsdf.render.pixel_rays``), in the box's unit frame."""
    ext = hi - lo
    scale = float(ext.max())
    r = pixel_rays(c2w, fov_x, width, height, lo, hi, (1, 1, 1), scale)  # one cell: (x - lo) / ext - 0.5
    origin = (r.origin.astype(np.float64) + 0.5) * ext / scale
    direction = r.direction.astype(np.float64) * ext
    return UnitRays(origin.astype(np.float32), direction.astype(np.float32), (r.t0 / scale).astype(np.float32),
                    (r.t1 / scale).astype(np.float32), r.pixel)


def cell_index(p, ext, n: int):
    """Flat index of the occupancy cell (``n`` per axis over [0, ext]) holding each point ``p`` (..., 3)."""
    i = jnp.clip(jnp.floor(p / jnp.asarray(ext, jnp.float32) * n), 0, n - 1).astype(jnp.int32)
    return (i[..., 0] * n + i[..., 1]) * n + i[..., 2]


def cell_points(ext, n: int, jitter):
    """One point per occupancy cell, (n^3, 3) in flat cell order: the cell's corner plus ``jitter``
    (n^3, 3) in [0, 1) of its size (0.5 for the centres)."""
    i = jnp.stack(jnp.meshgrid(*(jnp.arange(n),) * 3, indexing="ij"), -1).reshape(-1, 3)
    return (i + jitter) / n * jnp.asarray(ext, jnp.float32)


def update_occupancy(values, sigma, decay: float, threshold: float):
    """The occupancy grid after one update from ``sigma`` (n^3,) sampled in each cell: values
    ``max(decay * old, sigma)`` and bits where a value exceeds ``min(threshold, mean value)``
    (the paper's rule: a cell whose density is below both the threshold and the grid's mean is
    empty)."""
    values = jnp.maximum(decay * values, sigma)
    return values, values > jnp.minimum(threshold, values.mean())


def place_samples(bits, ext, n: int, origin, direction, t0, t1, key, dt: float, n_candidates: int,
                  n_samples: int, min_ratio: float):
    """Sample positions along a batch of rays, only in occupied cells (see the module's doc).

    Returns ``(points (S, 3), ray (S,), delta)``: ``ray`` is the sample's ray index, ascending,
    ``len(origin)`` for the unused tail of the budget; ``delta`` is the occupied length each
    sample stands for (one value for the batch)."""
    origin, direction, t0, t1 = (jnp.asarray(a) for a in (origin, direction, t0, t1))
    n_rays = origin.shape[0]
    k = jnp.arange(n_candidates, dtype=jnp.float32)
    t = t0[:, None] + (k + 0.5) * dt
    p = origin[:, None, :] + t[..., None] * direction[:, None, :]
    occ = (bits[cell_index(p, ext, n)] & (t < t1[:, None])).reshape(-1)
    count = jnp.cumsum(occ.astype(jnp.int32))
    total = count[-1]
    ratio = jnp.maximum(total.astype(jnp.float32) / n_samples, min_ratio)
    kj, kf = jax.random.split(key)
    u = (jnp.arange(n_samples, dtype=jnp.float32) + jax.random.uniform(kj, (n_samples,))) * ratio
    idx = jnp.floor(u).astype(jnp.int32)
    valid = idx < total
    c = jnp.clip(jnp.searchsorted(count, idx, side="right"), 0, n_rays * n_candidates - 1)
    ray, step = c // n_candidates, c % n_candidates
    ts = t0[ray] + (step + jax.random.uniform(kf, (n_samples,))) * dt
    points = origin[ray] + ts[:, None] * direction[ray]
    return points, jnp.where(valid, ray, n_rays), ratio * dt


def segmented_exclusive_cumsum(values, start):
    """Per segment (a new one where ``start`` is True) the sum of the earlier values in it."""

    def op(a, b):
        (va, fa), (vb, fb) = a, b
        return jnp.where(fb, vb, va + vb), fa | fb

    inclusive, _ = jax.lax.associative_scan(op, (values, start))
    return inclusive - values


def composite(sigma, rgb, ray, delta, n_rays: int):
    """Volume rendering of samples sorted by ``ray`` (``n_rays`` marks unused ones): per ray the
    opacity ``sum w`` and colour ``sum w c`` with ``w = T (1 - exp(-sigma delta))``, ``T`` the
    transmittance to the sample. Returns ``(alpha (n_rays,), colour (n_rays, 3), w (S,))``."""
    valid = ray < n_rays
    tau = jnp.where(valid, sigma * delta, 0.0)
    start = jnp.concatenate([jnp.ones(1, bool), ray[1:] != ray[:-1]])
    trans = jnp.exp(-segmented_exclusive_cumsum(tau, start))
    w = trans * -jnp.expm1(-tau)
    alpha = jax.ops.segment_sum(w, ray, n_rays + 1, indices_are_sorted=True)[:n_rays]
    colour = jax.ops.segment_sum(w[:, None] * rgb, ray, n_rays + 1, indices_are_sorted=True)[:n_rays]
    return alpha, colour, w
