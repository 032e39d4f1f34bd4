"""Multiresolution hash encoding (Mueller et al. 2022, "Instant neural graphics primitives") and
the small MLPs that turn its features into density and colour, in JAX.

Positions live in the unit cube [0, 1]^3. Level ``l`` has a grid of resolution
``N_l = floor(N_min b^l)`` with ``b = exp((ln N_max - ln N_min) / (L - 1))`` and a table of ``T``
entries of ``F`` features. A level whose ``(N_l + 1)^3`` grid vertices fit in ``T`` indexes them
densely (``i + j (N_l + 1) + k (N_l + 1)^2``, each vertex its own entry); a finer level hashes a
vertex to ``(i * 1 xor j * 2654435761 xor k * 805459861) mod T`` (the paper's primes, uint32
arithmetic). A point's features are the trilinear blend of its cell's 8 corner entries, the
levels concatenated. All levels share one flat table of ``L * T`` rows (level ``l`` at offset
``l * T``), so the lookup is one gather and its gradient one scatter-add.
"""
from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

PRIMES = (1, 2654435761, 805459861)
"""The spatial hash's per-axis multipliers (the paper's)."""


@dataclass(frozen=True)
class HashGrid:
    """Shape of the encoding: ``levels`` (L), ``log2_table`` (T = 2^log2_table), ``features`` (F),
    and the coarsest and finest resolutions ``n_min`` and ``n_max``."""

    levels: int = 16
    log2_table: int = 16
    features: int = 2
    n_min: int = 16
    n_max: int = 512

    @property
    def table_size(self) -> int:
        return 1 << self.log2_table

    @property
    def width(self) -> int:
        """Features per point: ``L * F``."""
        return self.levels * self.features

    def resolutions(self) -> np.ndarray:
        """Grid resolution of each level, coarse to fine (geometric steps from ``n_min`` to ``n_max``)."""
        if self.levels == 1:
            return np.array([self.n_min])
        b = np.exp((np.log(self.n_max) - np.log(self.n_min)) / (self.levels - 1))
        return np.floor(self.n_min * b ** np.arange(self.levels) + 1e-6).astype(np.int64)

    def dense(self) -> np.ndarray:
        """Per level: whether its (N + 1)^3 grid vertices fit in the table (indexed without hashing)."""
        return (self.resolutions() + 1) ** 3 <= self.table_size


def corner_index(corner, level_res: int, dense: bool, table_size: int):
    """Table row (within its level) of integer grid vertices ``corner`` (..., 3): dense for a
    level whose grid fits, else the spatial hash; always in [0, table_size)."""
    c = corner.astype(jnp.uint32)
    if dense:
        n = np.uint32(level_res + 1)
        return (c[..., 0] + c[..., 1] * n + c[..., 2] * (n * n)).astype(jnp.int32)
    h = (c[..., 0] * np.uint32(PRIMES[0])) ^ (c[..., 1] * np.uint32(PRIMES[1])) ^ (c[..., 2] * np.uint32(PRIMES[2]))
    return (h & np.uint32(table_size - 1)).astype(jnp.int32)


_OFFSETS = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)], np.int32)
"""The 8 corners of a cell, as (dx, dy, dz) offsets."""


def lookup(grid: HashGrid, x):
    """Rows of the flat table and trilinear weights for points ``x`` (n, 3) in [0, 1]^3: two arrays
    (n, L, 8), rows already offset by ``level * T``."""
    x = jnp.clip(x, 0.0, 1.0)
    rows, weights = [], []
    for level, (res, dense) in enumerate(zip(grid.resolutions(), grid.dense())):
        pos = x * float(res)
        base = jnp.clip(jnp.floor(pos), 0, res - 1)
        frac = pos - base
        corners = base.astype(jnp.int32)[:, None, :] + _OFFSETS[None]  # (n, 8, 3)
        w = jnp.prod(jnp.where(_OFFSETS[None] == 1, frac[:, None, :], 1.0 - frac[:, None, :]), axis=-1)
        rows.append(corner_index(corners, int(res), bool(dense), grid.table_size) + level * grid.table_size)
        weights.append(w)
    return jnp.stack(rows, 1), jnp.stack(weights, 1)


def encode(grid: HashGrid, table, x):
    """Features (n, L * F) of points ``x`` (n, 3) in [0, 1]^3 from ``table`` (L * T, F)."""
    rows, weights = lookup(grid, x)
    feats = (table[rows] * weights[..., None]).sum(2)  # (n, L, F)
    return feats.reshape(x.shape[0], grid.width)


def init_table(grid: HashGrid, key):
    """The table (L * T, F), uniform in [-1e-4, 1e-4] as in the paper, drawn from ``key``."""
    return jax.random.uniform(key, (grid.levels * grid.table_size, grid.features), minval=-1e-4, maxval=1e-4)


def init_mlp(key, sizes: tuple[int, ...]) -> list:
    """Layers ``[(W, b), ...]`` for the widths ``sizes``: Glorot-uniform weights from ``key``, zero biases."""
    layers = []
    for k, (a, b) in zip(jax.random.split(key, len(sizes) - 1), zip(sizes[:-1], sizes[1:])):
        lim = float(np.sqrt(6.0 / (a + b)))
        layers.append((jax.random.uniform(k, (a, b), minval=-lim, maxval=lim), jnp.zeros(b)))
    return layers


def mlp(layers: list, h):
    """ReLU between the layers, none after the last."""
    for i, (w, b) in enumerate(layers):
        h = h @ w + b
        if i + 1 < len(layers):
            h = jax.nn.relu(h)
    return h


@jax.custom_jvp
def trunc_exp(x):
    """The density activation: ``exp`` whose gradient uses the exponent clipped to [-15, 15] (the
    paper's: steep densities without exploding gradients)."""
    return jnp.exp(x)


@trunc_exp.defjvp
def _trunc_exp_jvp(primals, tangents):
    (x,), (t,) = primals, tangents
    return jnp.exp(x), t * jnp.exp(jnp.clip(x, -15.0, 15.0))


GEO = 15
"""Geometry features the density network passes to the colour network (the paper's 16 outputs
less the density)."""


def init_field(grid: HashGrid, hidden: int, key, view_dependent: bool = False) -> dict:
    """Parameters of the field: the hash table, the density MLP (L F -> hidden -> 1 + GEO) and the
    colour MLP (GEO [+ 3 view direction] -> hidden -> 3)."""
    kt, kd, kc = jax.random.split(key, 3)
    return {"table": init_table(grid, kt),
            "density": init_mlp(kd, (grid.width, hidden, 1 + GEO)),
            "colour": init_mlp(kc, (GEO + (3 if view_dependent else 0), hidden, 3))}


def density(grid: HashGrid, params: dict, x):
    """Density (n,) in 1 / (unit-cube length) at ``x`` (n, 3), and the geometry features (n, GEO)."""
    out = mlp(params["density"], encode(grid, params["table"], x))
    return trunc_exp(out[:, 0]), out[:, 1:]


def radiance(params: dict, geo, direction=None):
    """RGB in [0, 1] (n, 3) from the geometry features (and the view direction, if the field takes it)."""
    h = geo if direction is None else jnp.concatenate([geo, direction], -1)
    return jax.nn.sigmoid(mlp(params["colour"], h))
