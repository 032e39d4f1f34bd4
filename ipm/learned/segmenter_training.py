"""Training the learned segmenter (``ipm.learned.segmenter``) on the suite's own photographs.

Training photos: the dishes' and the buildings' random objects (``ipm.learned.data.draw_sample``,
a photo's range of elevations and lenses) rendered by ``ipm.render.photo_scene`` on random
grounds, walls, skies and suns, with a random plain colour or a seeded noise texture, then
JPEG-compressed at a random quality; the target is the object's silhouette. Every sample draws
from its own seed (``SEGMENTER_SEED_BASE + seed``, spawned), a range no case's sampler reaches.
``python -m ipm.learned.segmenter_training [OUT] [--threads N]`` makes the shipped weights (default
budget, seed 0; the shipped file was made with two threads).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Annotated

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ipm.errors import UserError
from ipm.learned.segmenter import FORMAT, SEG_RES, WIDTHS, UNet, _prepared, probabilities, shipped_path
from ipm.settings import Range, Settings, at_least

SEGMENTER_SEED_BASE = 20_000_000
"""Training photos draw from seeds ``SEGMENTER_SEED_BASE + seed`` (spawned per photo)."""
GENERATORS = ("dishes", "buildings", "buildings")
"""The generators whose objects the training photos show, in turn: a dish for every two buildings
(docs/decisions.md, "Segmenting a photograph")."""


@dataclass(frozen=True)
class SegmenterSettings(Settings):
    """How many training photos and steps the segmenter gets."""

    KIND = "segmenter setting"
    samples: Annotated[int, at_least(1)] = 4800
    held_out: Annotated[int, at_least(0)] = 200
    steps: Annotated[int, at_least(1)] = 6000
    batch: Annotated[int, at_least(1)] = 16
    learning_rate: Annotated[float, Range(1e-6, 1.0)] = 2e-3
    spp: Annotated[int, at_least(1)] = 32
    """Samples per pixel of the training renders."""


PROFILES = {"smoke": SegmenterSettings(samples=8, held_out=4, steps=4, batch=4, spp=4),
            "default": SegmenterSettings()}


def photo_sample(gen, rng: np.random.Generator, res: int = SEG_RES, spp: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """One training photo (res, res, 3) uint8 and its object mask (res, res) bool."""
    from ipm.io.views import jpeg_roundtrip, srgb_bytes
    from ipm.learned.data import PHOTO_ELEVATIONS, draw_sample, sample_lod
    from ipm.render.photo_scene import render_photo
    from ipm.render.textured import procedural_texture

    sample = draw_sample(gen, rng, res=res, elevations=PHOTO_ELEVATIONS)
    mesh_uv = gen.mesh(sample.x, sample_lod(gen)).uv
    textured = rng.random() < 0.5
    texture = procedural_texture(int(rng.integers(1 << 30)), 256) if textured else None
    plain = None if textured else tuple(rng.uniform(0.03, 0.9, 3))
    linear = render_photo(sample.vertices, sample.faces, mesh_uv, sample.c2w[None], sample.fov_x, res, res,
                          "random", int(rng.integers(1 << 20)), texture, plain, spp)[0]
    return jpeg_roundtrip(srgb_bytes(linear), int(rng.integers(60, 96))), sample.mask > 0.5


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
    from ipm.metrics.silhouette import view_ious

    held = view_ious(data["mask"][n:], probabilities(model, data["image"][n:]) > 0.5) if settings.held_out else None
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


def main(argv: list[str] | None = None) -> None:
    """``python -m ipm.learned.segmenter_training [OUT] [--threads N]``: train the shipped
    segmenter (default budget, seed 0; the shipped file: two threads)."""
    import argparse

    from ipm.runtime import configure_threads, set_mitsuba_variant

    ap = argparse.ArgumentParser(prog="python -m ipm.learned.segmenter_training", description=main.__doc__)
    ap.add_argument("out", nargs="?", default=None, help="weights file (default: the shipped one)")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads for XLA and Dr.Jit")
    args = ap.parse_args(argv)
    configure_threads(args.threads, "cpu")
    set_mitsuba_variant("cpu", args.threads)
    meta = prepare(args.out or shipped_path(), progress=True)
    print({k: meta[k] for k in ("held_out_mask_iou", "render_seconds", "train_seconds")})


if __name__ == "__main__":
    main()
