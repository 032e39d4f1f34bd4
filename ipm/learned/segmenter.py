"""A learned segmenter: a small U-Net that tells an object from its ground, its shadow and what
stands behind it in a photograph, trained on the suite's own photograph-like renders.

Training photos: the dishes' and the buildings' random objects (``ipm.learned.data.draw_sample``,
a photo's range of elevations and lenses) rendered by ``ipm.render.photo_scene`` on random
grounds, walls, skies and suns, with a random plain colour or a seeded noise texture, then
JPEG-compressed at a random quality; the target is the object's silhouette. Every sample draws
from its own seed (``SEGMENTER_SEED_BASE + seed``, spawned), a range no case's sampler reaches.
The network reads the photo at :data:`SEG_RES` pixels; its probability, resized to the photo's
size, starts OpenCV's GrabCut there (``ipm.segment.mask_from_photo``), which sets the edges.
"""
from __future__ import annotations

import io
import time
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Annotated

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ipm.errors import UserError
from ipm.settings import Range, Settings, at_least

SEG_RES = 96
"""Width and height (pixels) of the network's input and output."""
SEGMENTER_SEED_BASE = 20_000_000
"""Training photos draw from seeds ``SEGMENTER_SEED_BASE + seed`` (spawned per photo)."""
WIDTHS = (16, 32, 64, 64)
"""Channels of the encoder's four levels (full, 1/2, 1/4, 1/8 resolution)."""
GENERATORS = ("dishes", "buildings")
"""The generators whose objects the training photos show, in equal shares."""
FORMAT = "ipm-segmenter/1"


@dataclass(frozen=True)
class SegmenterSettings(Settings):
    """How many training photos and steps the segmenter gets."""

    KIND = "segmenter setting"
    samples: Annotated[int, at_least(1)] = 2400
    held_out: Annotated[int, at_least(0)] = 200
    steps: Annotated[int, at_least(1)] = 3000
    batch: Annotated[int, at_least(1)] = 16
    learning_rate: Annotated[float, Range(1e-6, 1.0)] = 2e-3
    spp: Annotated[int, at_least(1)] = 32
    """Samples per pixel of the training renders."""


PROFILES = {"smoke": SegmenterSettings(samples=8, held_out=4, steps=4, batch=4, spp=4),
            "default": SegmenterSettings()}


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


def photo_sample(gen, rng: np.random.Generator, res: int = SEG_RES, spp: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """One training photo (res, res, 3) uint8 and its object mask (res, res) bool."""
    from PIL import Image

    from ipm.io.views import srgb_bytes
    from ipm.learned.data import PHOTO_ELEVATIONS, draw_sample
    from ipm.render.photo_scene import render_photo
    from ipm.render.textured import procedural_texture

    sample = draw_sample(gen, rng, res=res, elevations=PHOTO_ELEVATIONS)
    mesh_uv = gen.mesh(sample.x, _lod(gen)).uv
    textured = rng.random() < 0.5
    texture = procedural_texture(int(rng.integers(1 << 30)), 256) if textured else None
    plain = None if textured else tuple(rng.uniform(0.03, 0.9, 3))
    linear = render_photo(sample.vertices, sample.faces, mesh_uv, sample.c2w[None], sample.fov_x, res, res,
                          "random", int(rng.integers(1 << 20)), texture, plain, spp)[0]
    buf = io.BytesIO()
    Image.fromarray(srgb_bytes(linear)).save(buf, format="JPEG", quality=int(rng.integers(60, 96)))
    return np.array(Image.open(io.BytesIO(buf.getvalue())).convert("RGB")), sample.mask > 0.5


def _lod(gen) -> int:
    from ipm.learned.data import sample_lod

    return sample_lod(gen)


def make_photos(n: int, seed: int, spp: int = 16, progress: bool = False) -> dict:
    """``n`` training photos, alternating over :data:`GENERATORS`: ``image`` (n, R, R, 3) uint8
    and ``mask`` (n, R, R) bool."""
    from tqdm import tqdm

    from ipm.generators import get_generator

    gens = [get_generator(g) for g in GENERATORS]
    images, masks = [], []
    seeds = np.random.SeedSequence(SEGMENTER_SEED_BASE + seed).spawn(n)
    for i, ss in enumerate(tqdm(seeds, desc="segmenter photos", disable=not progress, leave=False)):
        image, mask = photo_sample(gens[i % len(gens)], np.random.default_rng(ss), SEG_RES, spp)
        images.append(image)
        masks.append(mask)
    return {"image": np.stack(images), "mask": np.stack(masks)}


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


def mask_iou(prob: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per photo, the IoU of ``prob > 0.5`` with the true masks."""
    pred = prob > 0.5
    return (pred & mask).sum((1, 2)) / np.maximum((pred | mask).sum((1, 2)), 1)


def fit(settings: SegmenterSettings, seed: int, progress: bool = False, data: dict | None = None):
    """Train the segmenter: the model and its metadata (held-out mask IoU, seconds)."""
    import optax
    from tqdm import tqdm

    t0 = time.perf_counter()
    if data is None:
        data = make_photos(settings.samples + settings.held_out, seed, settings.spp, progress)
    n = settings.samples
    render_s = time.perf_counter() - t0
    model = UNet(jax.random.PRNGKey(seed))
    opt = optax.adam(optax.cosine_decay_schedule(settings.learning_rate, settings.steps))
    state = opt.init(eqx.filter(model, eqx.is_array))

    def loss_fn(model, x, y):
        logits = jax.vmap(model)(x)
        return jnp.mean(optax.sigmoid_binary_cross_entropy(logits, y))

    @eqx.filter_jit
    def step(model, state, x, y):
        loss, grads = eqx.filter_value_and_grad(loss_fn)(model, x, y)
        updates, state = opt.update(grads, state, model)
        return eqx.apply_updates(model, updates), state, loss

    rng = np.random.default_rng(seed)
    losses = []
    bar = tqdm(range(settings.steps), desc="train segmenter", disable=not progress, leave=False)
    for _ in bar:
        idx = rng.integers(0, n, settings.batch)
        x, y = data["image"][idx], data["mask"][idx]
        flip = rng.random(settings.batch) < 0.5  # mirror images: a photo's object faces either way
        x, y = np.where(flip[:, None, None, None], x[:, :, ::-1], x), np.where(flip[:, None, None], y[:, :, ::-1], y)
        model, state, loss = step(model, state, jnp.asarray(_prepared(x)), jnp.asarray(y, jnp.float32))
        losses.append(float(loss))
        if len(losses) % 100 == 0:
            bar.set_postfix(loss=f"{np.mean(losses[-100:]):.4f}")
    held = mask_iou(probabilities(model, data["image"][n:]), data["mask"][n:]) if settings.held_out else None
    meta = {"seed": seed, "settings": asdict(settings), "res": SEG_RES, "widths": list(WIDTHS),
            "generators": list(GENERATORS), "final_loss": float(np.mean(losses[-50:])),
            "held_out_mask_iou": None if held is None else {"mean": float(held.mean()), "worst": float(held.min())},
            "render_seconds": round(render_s, 1), "train_seconds": round(time.perf_counter() - t0 - render_s, 1)}
    return model, meta


def prepare(out, profile: str = "default", seed: int = 0, progress: bool = False) -> dict:
    """Train the segmenter with ``profile``'s budget from ``seed`` and write it to ``out``."""
    from ipm.learned.network import save

    if profile not in PROFILES:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(PROFILES)})")
    model, meta = fit(PROFILES[profile], seed, progress)
    save(model, out, meta, FORMAT)
    return meta


def shipped_path():
    from pathlib import Path

    return Path(__file__).parent / "weights" / "segmenter.json"


@lru_cache(maxsize=2)
def load(path: str | None = None) -> UNet:
    """The segmenter from ``path``, else the shipped one (``UserError`` if missing or malformed)."""
    from ipm.learned.network import load_model

    model, _ = load_model(path or shipped_path(), FORMAT, "a segmenter's", lambda r: UNet(jax.random.PRNGKey(0)))
    return model


def probability(rgb: np.ndarray, model: UNet | None = None) -> np.ndarray:
    """The object probability (H, W) of a photo (H, W, 3; uint8 or float in [0, 1]), read at
    :data:`SEG_RES` and resized back."""
    from PIL import Image

    rgb = np.asarray(rgb)[..., :3]
    img8 = rgb if rgb.dtype == np.uint8 else np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8)
    small = np.array(Image.fromarray(img8).resize((SEG_RES, SEG_RES), Image.BILINEAR))
    prob = probabilities(model or load(), small[None])[0]
    return np.array(Image.fromarray(prob.astype(np.float32)).resize((rgb.shape[1], rgb.shape[0]), Image.BILINEAR))


def main(argv: list[str] | None = None) -> None:
    """``python -m ipm.learned.segmenter [OUT]``: train the shipped segmenter (default budget, seed 0,
    one thread)."""
    import sys

    from ipm.runtime import configure_threads, set_mitsuba_variant

    argv = sys.argv[1:] if argv is None else argv
    configure_threads(1, "cpu")
    set_mitsuba_variant("cpu", 1)
    meta = prepare(argv[0] if argv else shipped_path(), progress=True)
    print({k: meta[k] for k in ("held_out_mask_iou", "render_seconds", "train_seconds")})


if __name__ == "__main__":
    main()
