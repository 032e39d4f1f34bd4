"""The occupancy network after Mescheder et al. 2019, "Occupancy Networks": an image encoder (the
regressor's convolutions, ``ipm.learned.network``) gives a latent code, which with the camera
numbers conditions an MLP decoder from a point's Fourier features to an occupancy logit.

The conditioning is per layer, as the paper's conditional batch norm is: the code sets a bias of
each hidden layer (computed once per view), so a point costs only the decoder's matrix products.
Weights go into one JSON file through ``ipm.learned.network.save`` and ``load_model``.
"""
from __future__ import annotations

from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

FORMAT = "ipm-occnet/1"
LATENT = 128
"""Width of the image's latent code (before the camera numbers join it)."""
HIDDEN = 128
"""Width of the decoder's hidden layers."""
BLOCKS = 3
"""Residual layers of the decoder after its first one."""
FREQUENCIES = 6
"""Octaves of the points' Fourier features: sin and cos of ``2^k pi p``, k < FREQUENCIES."""


def fourier(p, frequencies: int = FREQUENCIES):
    """A point (3,) and its Fourier features, (3 + 6 * frequencies,)."""
    scaled = p[None, :] * (jnp.pi * 2.0 ** jnp.arange(frequencies))[:, None]
    return jnp.concatenate([p, jnp.sin(scaled).ravel(), jnp.cos(scaled).ravel()])


class OccupancyNet(eqx.Module):
    """Image (C, R, R), camera numbers (N_COND,) and points (n, 3) in the view's local frame ->
    occupancy logits (n,)."""

    convs: list
    encode: eqx.nn.Linear
    condition: eqx.nn.Linear
    first: eqx.nn.Linear
    blocks: list
    out: eqx.nn.Linear

    def __init__(self, in_channels: int, res: int, n_cond: int, key):
        from ipm.learned.network import CHANNELS, conv_features_size, conv_stack

        keys = jax.random.split(key, len(CHANNELS) + 4 + BLOCKS)
        self.convs = conv_stack(in_channels, keys[:len(CHANNELS)])
        k = keys[len(CHANNELS):]
        self.encode = eqx.nn.Linear(conv_features_size(res), LATENT, key=k[0])
        self.condition = eqx.nn.Linear(LATENT + n_cond, HIDDEN * (BLOCKS + 1), key=k[1])
        self.first = eqx.nn.Linear(3 + 6 * FREQUENCIES, HIDDEN, key=k[2])
        self.blocks = [eqx.nn.Linear(HIDDEN, HIDDEN, key=kb) for kb in k[4:]]
        self.out = eqx.nn.Linear(HIDDEN, 1, key=k[3])

    def code(self, image, cond):
        """The view's conditioning: one bias per hidden layer, (BLOCKS + 1, HIDDEN)."""
        from ipm.learned.network import conv_features

        latent = jax.nn.relu(self.encode(conv_features(self.convs, image)))
        return self.condition(jnp.concatenate([latent, cond])).reshape(BLOCKS + 1, HIDDEN)

    def decode(self, code, points):
        """Occupancy logits (n,) of ``points`` (n, 3) under a view's :meth:`code`."""

        def one(p):
            h = jax.nn.relu(self.first(fourier(p)) + code[0])
            for layer, bias in zip(self.blocks, code[1:]):
                h = h + jax.nn.relu(layer(h) + bias)
            return self.out(h)[0]

        return jax.vmap(one)(points)

    def __call__(self, image, cond, points):
        return self.decode(self.code(image, cond), points)


LAYOUT = {"latent": LATENT, "hidden": HIDDEN, "blocks": BLOCKS, "frequencies": FREQUENCIES}
"""The decoder's shape, written with the weights: a file of another shape is refused."""


def skeleton(record: dict) -> OccupancyNet:
    """A model of the layout a weights file's record names (weights to be filled in); ``UserError``
    for a file made for another decoder shape."""
    from ipm.errors import UserError

    if any(record.get(k) != v for k, v in LAYOUT.items()):
        raise UserError("the occupancy-network weights were made for another network shape; make them again")
    return OccupancyNet(int(record["in_channels"]), int(record["res"]), int(record["n_cond"]), jax.random.PRNGKey(0))


def save(model: OccupancyNet, path: str | Path, meta: dict) -> None:
    """Write the model and ``meta`` into one JSON file, atomically (``ipm.learned.network.save``)."""
    from ipm.learned.network import save as save_model

    save_model(model, path, {**meta, **LAYOUT}, fmt=FORMAT)


def load(path: str | Path, expect_generator: str | None = None) -> tuple[OccupancyNet, dict]:
    """The model and its metadata from :func:`save`'s file (``UserError`` for a missing, malformed
    or foreign file, one made for another generator, or for another decoder layout)."""
    from ipm.learned.network import load_model

    return load_model(path, FORMAT, "an occupancy network's", skeleton, expect_generator)


_code = eqx.filter_jit(lambda m, image, cond: m.code(image, cond))
_probabilities = eqx.filter_jit(lambda m, code, points: jax.nn.sigmoid(m.decode(code, points)))


def field(model: OccupancyNet, image: np.ndarray, cond: np.ndarray, points: np.ndarray,
          chunk: int = 32768) -> np.ndarray:
    """Occupancy probabilities (n,) of local ``points`` (n, 3) for one view, in fixed-size chunks
    (one compilation)."""
    code = _code(model, jnp.asarray(image), jnp.asarray(cond))
    n = len(points)
    padded = np.zeros((-(-n // chunk) * chunk, 3), np.float32)
    padded[:n] = points
    parts = [np.asarray(_probabilities(model, code, jnp.asarray(padded[i:i + chunk]))) for i in range(0, len(padded), chunk)]
    return np.concatenate(parts)[:n]
