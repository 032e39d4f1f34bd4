"""A learned segmenter: a small U-Net that tells an object from its ground, its shadow and what
stands behind it in a photograph, trained on the suite's own photograph-like renders
(``ipm.learned.segmenter_training``; shipped as ``weights/segmenter.json``).

The network reads the photo at :data:`SEG_RES` pixels; its probability, resized to the photo's
size, starts OpenCV's GrabCut there (``ipm.segment.mask_from_photo``), which sets the edges.
"""
from __future__ import annotations

from functools import lru_cache

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

SEG_RES = 96
"""Width and height (pixels) of the network's input and output."""
WIDTHS = (16, 32, 64, 64)
"""Channels of the encoder's four levels (full, 1/2, 1/4, 1/8 resolution)."""
FORMAT = "ipm-segmenter/1"


class UNet(eqx.Module):
    """Photo (3, R, R) in [-0.5, 0.5] -> object logits (R, R): a four-level encoder of 3 x 3
    convolutions (stride 2 between levels) and a decoder that upsamples and joins each level's
    features, R a multiple of 8."""

    down: list
    up: list
    out: eqx.nn.Conv2d

    def __init__(self, key):
        keys = iter(jax.random.split(key, 2 * len(WIDTHS) + len(WIDTHS)))
        widths = (3,) + WIDTHS
        self.down = [[eqx.nn.Conv2d(a, b, 3, stride=1 if i == 0 else 2, padding=1, key=next(keys)),
                      eqx.nn.Conv2d(b, b, 3, padding=1, key=next(keys))]
                     for i, (a, b) in enumerate(zip(widths[:-1], widths[1:]))]
        self.up = [eqx.nn.Conv2d(WIDTHS[i + 1] + WIDTHS[i], WIDTHS[i], 3, padding=1, key=next(keys))
                   for i in range(len(WIDTHS) - 1)]
        self.out = eqx.nn.Conv2d(WIDTHS[0], 1, 1, key=next(keys))

    def __call__(self, image):
        skips, h = [], image
        for a, b in self.down:
            h = jax.nn.relu(b(jax.nn.relu(a(h))))
            skips.append(h)
        for i in reversed(range(len(self.up))):
            skip = skips[i]
            h = jax.image.resize(h, (h.shape[0],) + skip.shape[1:], "bilinear")
            h = jax.nn.relu(self.up[i](jnp.concatenate([h, skip])))
        return self.out(h)[0]


def _prepared(images: np.ndarray) -> np.ndarray:
    """uint8 photos (n, R, R, 3) as the network reads them: (n, 3, R, R) in [-0.5, 0.5]."""
    return np.transpose(images.astype(np.float32) / 255.0 - 0.5, (0, 3, 1, 2))


@lru_cache(maxsize=1)
def _batched():
    return eqx.filter_jit(lambda m, x: jax.vmap(m)(x))


def probabilities(model: UNet, images: np.ndarray, chunk: int = 64) -> np.ndarray:
    """The object probability (n, R, R) of uint8 photos (n, R, R, 3) at the network's size."""
    fn = _batched()
    return np.concatenate([np.asarray(jax.nn.sigmoid(fn(model, jnp.asarray(_prepared(images[i:i + chunk])))))
                           for i in range(0, len(images), chunk)])


def shipped_path():
    from pathlib import Path

    return Path(__file__).parent / "weights" / "segmenter.json"


@lru_cache(maxsize=2)
def load(path: str | None = None) -> UNet:
    """The segmenter from ``path``, else the shipped one (``UserError`` if missing or malformed)."""
    from ipm.learned.network import load_model

    model, _ = load_model(path or shipped_path(), FORMAT, "a segmenter's", lambda r: UNet(jax.random.PRNGKey(0)))
    return model


def probability(img8: np.ndarray, model: UNet | None = None) -> np.ndarray:
    """The object probability (H, W) of an 8-bit RGB photo (H, W, 3), read at :data:`SEG_RES`
    and resized back."""
    from PIL import Image

    small = np.array(Image.fromarray(img8).resize((SEG_RES, SEG_RES), Image.BILINEAR))
    prob = probabilities(model or load(), small[None])[0]
    return np.array(Image.fromarray(prob.astype(np.float32)).resize((img8.shape[1], img8.shape[0]), Image.BILINEAR))


