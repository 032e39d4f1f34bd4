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

SEG_RES = 128
"""Width and height (pixels) of the shipped network's input and output."""
WIDTHS = (24, 48, 96, 160, 192)
"""Channels of the shipped network's encoder levels (full resolution, then halved at each level)."""
FORMAT = "ipm-segmenter/1"


class UNet(eqx.Module):
    """Photo (3, R, R) in [-0.5, 0.5] -> object logits (R, R): an encoder of 3 x 3 convolutions
    (stride 2 between levels, ``widths`` channels) and a decoder that upsamples and joins each
    level's features; ``res`` (a multiple of 2 ** (levels - 1)) is the size it reads photos at."""

    down: list
    up: list
    out: eqx.nn.Conv2d
    res: int = eqx.field(static=True)

    def __init__(self, key, widths: tuple = WIDTHS, res: int = SEG_RES):
        keys = iter(jax.random.split(key, 3 * len(widths)))
        chans = (3,) + tuple(widths)
        self.down = [[eqx.nn.Conv2d(a, b, 3, stride=1 if i == 0 else 2, padding=1, key=next(keys)),
                      eqx.nn.Conv2d(b, b, 3, padding=1, key=next(keys))]
                     for i, (a, b) in enumerate(zip(chans[:-1], chans[1:]))]
        self.up = [eqx.nn.Conv2d(widths[i + 1] + widths[i], widths[i], 3, padding=1, key=next(keys))
                   for i in range(len(widths) - 1)]
        self.out = eqx.nn.Conv2d(widths[0], 1, 1, key=next(keys))
        self.res = int(res)

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


def network_input(images):
    """Photos (n, R, R, 3) of 0-255 values (NumPy or JAX) as the network reads them: (n, 3, R, R)
    in [-0.5, 0.5]."""
    return (images.astype(np.float32) / 255.0 - 0.5).transpose(0, 3, 1, 2)


@lru_cache(maxsize=1)
def _batched():
    return eqx.filter_jit(lambda m, x: jax.vmap(m)(x))


def probabilities(model: UNet, images: np.ndarray, chunk: int = 64) -> np.ndarray:
    """The object probability (n, R, R) of uint8 photos (n, R, R, 3) at the network's size."""
    fn = _batched()
    return np.concatenate([np.asarray(jax.nn.sigmoid(fn(model, jnp.asarray(network_input(images[i:i + chunk])))))
                           for i in range(0, len(images), chunk)])


def shipped_path():
    from pathlib import Path

    return Path(__file__).parent / "weights" / "segmenter.json"


def read(path=None) -> tuple[UNet, dict]:
    """The segmenter from ``path``, else the shipped one, and its file's metadata without the
    weights (``UserError`` if missing or malformed)."""
    from ipm.learned.network import load_model

    model, record = load_model(path or shipped_path(), FORMAT, "a segmenter's",
                               lambda r: UNet(jax.random.PRNGKey(0), tuple(r["widths"]), r["res"]))
    return model, {k: v for k, v in record.items() if k != "format"}


@lru_cache(maxsize=2)
def load(path: str | None = None) -> UNet:
    """The segmenter from ``path``, else the shipped one (``UserError`` if missing or malformed)."""
    return read(path)[0]


def probability(img8: np.ndarray, model: UNet | None = None) -> np.ndarray:
    """The object probability (H, W) of an 8-bit RGB photo (H, W, 3), read at the network's size
    and resized back."""
    from PIL import Image

    model = model or load()
    small = np.array(Image.fromarray(img8).resize((model.res, model.res), Image.BILINEAR))
    prob = probabilities(model, small[None])[0]
    return np.array(Image.fromarray(prob.astype(np.float32)).resize((img8.shape[1], img8.shape[0]), Image.BILINEAR))


