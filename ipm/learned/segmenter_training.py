"""Training the learned segmenter (``ipm.learned.segmenter``) on the suite's own photographs.

Training photos: the dishes' and the buildings' random objects (``ipm.learned.data.draw_sample``,
a photo's range of elevations and lenses) rendered by ``ipm.render.photo_scene`` on random
grounds, walls, skies and suns, in a random plain colour, a seeded noise texture or their class's
reference materials, then JPEG-compressed at a random quality; the target is the object's
silhouette. Every sample draws from its own seed (``SEGMENTER_SEED_BASE + seed``, spawned), a
range no case's sampler reaches. The shipped weights (default budget, seed 0) were made in two
steps: ``python -m ipm.learned.segmenter_training --render-photos A.npz --count 4150`` and
``... --render-photos B.npz --start 4150`` on the CPU (Mitsuba), then
``python -m ipm.learned.segmenter_training --photos A.npz B.npz --device cuda`` on one GPU (about
5 minutes there; about 34 hours on two CPU threads).
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
from ipm.learned.segmenter import FORMAT, SEG_RES, WIDTHS, UNet, network_input, probabilities, read, shipped_path
from ipm.metrics.silhouette import view_ious
from ipm.settings import Range, Settings, at_least

SEGMENTER_SEED_BASE = 20_000_000
"""Training photos draw from seeds ``SEGMENTER_SEED_BASE + seed`` (spawned per photo)."""
GENERATORS = ("dishes", "buildings", "buildings")
"""The generators whose objects the training photos show, in turn: a dish for every two buildings
(docs/decisions.md, "Segmenting a photograph")."""
STEMMED_SEED_BASE = 21_000_000
"""Photos of vessels on a stem (:func:`stemmed_vessel`) draw from seeds ``STEMMED_SEED_BASE + seed``."""


@dataclass(frozen=True)
class SegmenterSettings(Settings):
    """How many training photos and steps the segmenter gets."""

    KIND = "segmenter setting"
    samples: Annotated[int, at_least(1)] = 8000
    held_out: Annotated[int, at_least(0)] = 300
    steps: Annotated[int, at_least(1)] = 20000
    batch: Annotated[int, at_least(1)] = 32
    learning_rate: Annotated[float, Range(1e-6, 1.0)] = 2e-3
    spp: Annotated[int, at_least(1)] = 32
    """Samples per pixel of the training renders."""


PROFILES = {"smoke": SegmenterSettings(samples=8, held_out=4, steps=4, batch=4, spp=4),
            "default": SegmenterSettings()}
STEMMED_SHARE = 0.25
"""The share of each batch drawn from photos of vessels on a stem, where a training is given them."""


def stemmed_vessel(gen, rng: np.random.Generator) -> np.ndarray:
    """Parameters of a dishes vessel on a foot and a stem, without a handle (a wine or cocktail glass,
    an egg cup, a sundae dish): the profile's lowest point a foot (radius 0.15-0.4), the next two to
    four a stem (0.02-0.07), the rest a bowl from 0.06-0.25 to a rim of 0.2-0.7 by a power curve
    with a bulge or waist, height 0.6-1.25. The dishes sampler (the test split's) draws no stem, so
    photos of its draws never show the ground between a bowl and its foot."""
    from ipm.generators.dishes import N_PROFILE, power_profile

    spec = gen.spec
    x = spec.default.copy()
    stem = int(rng.integers(2, 5))  # profile points 1..stem
    x[0] = rng.uniform(1.5, 4.0)
    x[1:stem + 1] = rng.uniform(0.2, 0.7) * rng.uniform(0.85, 1.15, stem)
    t = np.linspace(0.0, 1.0, N_PROFILE - stem - 1)
    r0, r1 = rng.uniform(0.6, 2.5), rng.uniform(2.0, 7.0)
    gamma = float(np.exp(rng.uniform(np.log(0.3), np.log(2.0))))
    x[stem + 1:N_PROFILE] = power_profile(t, r0, r1, gamma, rng.uniform(-0.5, 1.5))
    x[spec.index["y_scale"]] = rng.uniform(0.6, 1.25)
    x[spec.index["has_handle"]] = 0.0
    return spec.clip(x)


def photo_sample(gen, rng: np.random.Generator, res: int = SEG_RES, spp: int = 16,
                 stemmed: bool = False) -> tuple[bytes, np.ndarray]:
    """One training photo as a JPEG file's bytes (res x res) and its object mask (res, res) bool.
    The object (``stemmed``: a dishes vessel on a stem, :func:`stemmed_vessel`) wears, in equal
    shares, a plain colour, a seeded noise texture, or the materials the references' views wear
    (``ipm.render.appearance``: glazes and prints; brick, render and tiles)."""
    from ipm.io.views import jpeg_bytes, srgb_bytes
    from ipm.learned.data import PHOTO_ELEVATIONS, draw_sample, sample_lod
    from ipm.render.photo_scene import render_photo

    x = stemmed_vessel(gen, rng) if stemmed else None
    sample = draw_sample(gen, rng, res=res, elevations=PHOTO_ELEVATIONS, x=x)
    mesh = gen.mesh(sample.x, sample_lod(gen))
    dress = rng.random()
    texture, plain, labels = None, None, None
    if dress < 1 / 3:
        plain = tuple(rng.uniform(0.03, 0.9, 3))
    elif dress < 2 / 3:
        from ipm.render.textured import procedural_texture

        texture = procedural_texture(int(rng.integers(1 << 30)), 256)
    else:
        texture, labels = _materials(gen, mesh, int(rng.integers(1 << 30))), mesh.labels
    linear = render_photo(sample.vertices, sample.faces, mesh.uv, sample.c2w[None], sample.fov_x, res, res,
                          "random", int(rng.integers(1 << 20)), texture, plain, spp, labels)[0]
    return jpeg_bytes(srgb_bytes(linear), int(rng.integers(60, 96))), sample.mask > 0.5


def _materials(gen, mesh, seed: int) -> dict:
    """Each part's texture as a reference view would bake it (128 texels a side: a training photo
    is small)."""
    from ipm.render.appearance import BUILDING_PARTS, reference_textures

    if gen.name == "dishes":
        return reference_textures("cup", mesh.vertices, mesh.faces, mesh.labels, mesh.uv, seed, size=128)
    parts = {int(k): BUILDING_PARTS[mesh.part_names[k]] for k in np.unique(mesh.labels)}
    return reference_textures("building", mesh.vertices, mesh.faces, mesh.labels, mesh.uv, seed, parts, size=128)


def make_photos(n: int, seed: int, spp: int = 16, progress: bool = False, start: int = 0,
                stemmed: bool = False) -> dict:
    """Training photos ``start`` to ``start + n`` of ``seed``'s sequence, alternating over
    :data:`GENERATORS` (``stemmed``: of the stemmed vessels' own sequence, :func:`stemmed_vessel`):
    ``jpeg`` (their files' bytes, a list), ``mask`` (n, R, R) bool and ``ranges`` (``[[start, start +
    n]]``). Each photo draws from its own spawned seed, so ranges made apart join into the same set."""
    from tqdm import tqdm

    from ipm.generators import get_generator

    gens = [get_generator(g) for g in (("dishes",) if stemmed else GENERATORS)]
    files, masks = [], []
    base = STEMMED_SEED_BASE if stemmed else SEGMENTER_SEED_BASE
    seeds = np.random.SeedSequence(base + seed).spawn(start + n)[start:]
    for i, ss in enumerate(tqdm(seeds, desc="segmenter photos", disable=not progress, leave=False), start):
        data, mask = photo_sample(gens[i % len(gens)], np.random.default_rng(ss), SEG_RES, spp, stemmed)
        files.append(data)
        masks.append(mask)
    return {"jpeg": files, "mask": np.stack(masks), "ranges": [[start, start + n]]}


def decoded(data: dict) -> np.ndarray:
    """The photos of :func:`make_photos` as uint8 images (n, R, R, 3)."""
    from ipm.io.views import jpeg_decode

    return np.stack([jpeg_decode(b) for b in data["jpeg"]])


def save_photos(path, data: dict) -> None:
    """Write :func:`make_photos`'s photos (the JPEG files end to end, their offsets, the masks as
    bits, the photos' index ranges) to one compressed ``.npz`` file, atomically."""
    from ipm.io.atomic import atomic_path

    ends = np.cumsum([len(b) for b in data["jpeg"]])
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, jpeg=np.frombuffer(b"".join(data["jpeg"]), np.uint8), ends=ends,
                            mask=np.packbits(data["mask"], axis=-1), res=data["mask"].shape[-1],
                            ranges=np.asarray(data["ranges"], np.int64).reshape(-1, 2))


def load_photos(*paths) -> dict:
    """The photos of one or more :func:`save_photos` files, joined in the order given."""
    files, masks, ranges = [], [], []
    for path in paths:
        try:
            with np.load(path) as z:
                blob, ends, res = z["jpeg"].tobytes(), z["ends"], int(z["res"])
                masks.append(np.unpackbits(z["mask"], axis=-1, count=res).astype(bool))
                ranges += z["ranges"].tolist() if "ranges" in z else []
        except (OSError, KeyError, ValueError) as exc:
            raise UserError(f"unreadable training photos {path}: {exc}") from None
        files += [blob[a:b] for a, b in zip(np.concatenate([[0], ends[:-1]]), ends)]
    return {"jpeg": files, "mask": np.concatenate(masks), "ranges": ranges}


def _augmented(images, masks, key, batch: int):
    """A batch drawn from the photos (on the device): uint8 (N, R, R, 3) -> the network's input
    (batch, 3, R, R), each mirrored at random (a photo's object faces either way) and its exposure,
    contrast and white balance varied, and the masks (batch, R, R) to match."""
    k_idx, k_flip, k_gain, k_con, k_white = jax.random.split(key, 5)
    idx = jax.random.randint(k_idx, (batch,), 0, images.shape[0])
    x, y = images[idx].astype(jnp.float32) / 255.0, masks[idx].astype(jnp.float32)
    flip = jax.random.bernoulli(k_flip, 0.5, (batch,))
    x = jnp.where(flip[:, None, None, None], x[:, :, ::-1], x)
    y = jnp.where(flip[:, None, None], y[:, :, ::-1], y)
    mean = x.mean(axis=(1, 2, 3), keepdims=True)
    contrast = jax.random.uniform(k_con, (batch, 1, 1, 1), minval=0.8, maxval=1.2)
    gain = jax.random.uniform(k_gain, (batch, 1, 1, 1), minval=0.8, maxval=1.2)
    white = jax.random.uniform(k_white, (batch, 1, 1, 3), minval=0.92, maxval=1.08)
    x = jnp.clip(((x - mean) * contrast + mean) * gain * white, 0.0, 1.0)
    return network_input(x * 255.0), y


def _summary(ious: np.ndarray | None) -> dict | None:
    """Held-out photos' mask IoUs as their mean and worst (None where none were held out)."""
    return None if ious is None else {"mean": float(ious.mean()), "worst": float(ious.min())}


def fit(settings: SegmenterSettings, seed: int, progress: bool = False, data: dict | None = None,
        init: tuple | None = None, stemmed: dict | None = None, stemmed_share: float = STEMMED_SHARE):
    """Train the segmenter: the model and its metadata (held-out mask IoU, seconds). The photos
    (rendered here unless ``data`` gives them, as :func:`make_photos` returns them) stay on JAX's
    device; each step draws its batch there, augmented (:func:`_augmented`). The loss: binary
    cross-entropy plus one minus each photo's soft IoU. ``init`` (a model and its metadata, as
    ``ipm.learned.segmenter.read`` returns them) starts from a trained network instead of ``seed``'s.
    ``stemmed``: photos of vessels on a stem (``make_photos(stemmed=True)``), ``stemmed_share`` of
    every batch, the main set's share of them held out."""
    import optax
    from tqdm import tqdm

    t0 = time.perf_counter()
    if data is None:
        data = make_photos(settings.samples + settings.held_out, seed, settings.spp, progress)
    if len(data["jpeg"]) < settings.samples + settings.held_out:
        raise UserError(f"{len(data['jpeg'])} training photos, the budget needs "
                        f"{settings.samples + settings.held_out}")
    images, n = decoded(data), settings.samples
    render_s = time.perf_counter() - t0
    model = UNet(jax.random.PRNGKey(seed), WIDTHS, images.shape[1]) if init is None else init[0]
    if model.res != images.shape[1]:
        raise UserError(f"the network reads {model.res} px photos, the training photos are {images.shape[1]} px")
    opt = optax.adam(optax.cosine_decay_schedule(settings.learning_rate, settings.steps))
    state = opt.init(eqx.filter(model, eqx.is_array))
    train_x, train_y = jnp.asarray(images[:n]), jnp.asarray(data["mask"][:n])
    n_stem = 0 if stemmed is None else round(settings.batch * stemmed_share)
    if n_stem:
        stem_images = decoded(stemmed)
        stem_n = len(stem_images) - round(len(stem_images) * settings.held_out / (n + settings.held_out))
        stem_x, stem_y = jnp.asarray(stem_images[:stem_n]), jnp.asarray(stemmed["mask"][:stem_n])

    def loss_fn(model, x, y):
        logits = jax.vmap(model)(x)
        p = jax.nn.sigmoid(logits)
        soft_iou = (p * y).sum((1, 2)) / ((p + y - p * y).sum((1, 2)) + 1.0)
        return jnp.mean(optax.sigmoid_binary_cross_entropy(logits, y)) + jnp.mean(1.0 - soft_iou)

    @eqx.filter_jit
    def step(model, state, xs, ys, key, extra=None):
        x, y = _augmented(xs, ys, key, settings.batch - n_stem)
        if n_stem:
            x2, y2 = _augmented(*extra, jax.random.fold_in(key, 1), n_stem)
            x, y = jnp.concatenate([x, x2]), jnp.concatenate([y, y2])
        loss, grads = eqx.filter_value_and_grad(loss_fn)(model, x, y)
        updates, state = opt.update(grads, state, model)
        return eqx.apply_updates(model, updates), state, loss

    key = jax.random.PRNGKey(seed + 1)
    losses = []
    bar = tqdm(range(settings.steps), desc="train segmenter", disable=not progress, leave=False)
    for i in bar:
        model, state, loss = step(model, state, train_x, train_y, jax.random.fold_in(key, i),
                                  (stem_x, stem_y) if n_stem else None)
        losses.append(loss)
        if (i + 1) % 100 == 0:
            bar.set_postfix(loss=f"{float(np.mean(losses[-100:])):.4f}")
    losses = [float(v) for v in losses[-50:]]
    held = stem_held = None
    if settings.held_out:  # each held-out photo's mask IoU (1 where both are empty)
        held = view_ious(probabilities(model, images[n:]) > 0.5, data["mask"][n:] > 0.5)
        if n_stem and stem_n < len(stem_images):
            stem_held = view_ious(probabilities(model, stem_images[stem_n:]) > 0.5, stemmed["mask"][stem_n:] > 0.5)
    meta = {"seed": seed, "settings": asdict(settings), "res": model.res,
            "widths": [a.out_channels for a, _ in model.down], "generators": list(GENERATORS),
            "photos": data.get("ranges", []), "final_loss": float(np.mean(losses)), "device": jax.default_backend(),
            "held_out_mask_iou": _summary(held),
            "render_seconds": round(render_s, 1), "train_seconds": round(time.perf_counter() - t0 - render_s, 1)}
    if init is not None:
        meta["init"] = init[1]
    if n_stem:
        meta["stemmed_photos"], meta["stemmed_share"] = stemmed.get("ranges", []), stemmed_share
        if stem_held is not None:
            meta["stemmed_held_out_mask_iou"] = _summary(stem_held)
    return model, meta


def prepare(out, profile: str = "default", seed: int = 0, progress: bool = False, data: dict | None = None,
            init: tuple | None = None, stemmed: dict | None = None) -> dict:
    """Train the segmenter with ``profile``'s budget from ``seed`` (on ``data``'s photos where
    given; from ``init``'s network where given; with ``stemmed``'s photos of vessels on a stem where
    given) and write it to ``out``."""
    from ipm.learned.network import save

    if profile not in PROFILES:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(PROFILES)})")
    model, meta = fit(PROFILES[profile], seed, progress, data, init, stemmed)
    save(model, out, meta, FORMAT)
    return meta


def main(argv: list[str] | None = None) -> None:
    """``python -m ipm.learned.segmenter_training [OUT] [--threads N] [--photos F ...] [--device D]
    [--init W]``: train the shipped segmenter (default budget, seed 0) on photos rendered here or
    read from ``--photos`` files, from new weights or ``--init``'s; ``--render-photos F --start A
    --count N`` renders a range of them to ``F``."""
    import argparse

    from ipm.runtime import configure_threads, set_mitsuba_variant

    ap = argparse.ArgumentParser(prog="python -m ipm.learned.segmenter_training", description=main.__doc__)
    ap.add_argument("out", nargs="?", default=None, help="weights file (default: the shipped one)")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads for XLA and Dr.Jit")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="where JAX trains")
    ap.add_argument("--photos", nargs="+", default=None, help="training photos written by --render-photos, "
                    "in order (default: render them here)")
    ap.add_argument("--seed", type=int, default=0, help="the network's initial weights and batches (the "
                    "shipped one: 0; the photos are seed 0's either way)")
    ap.add_argument("--render-photos", default=None, metavar="FILE", help="only render photos to FILE")
    ap.add_argument("--start", type=int, default=0, help="with --render-photos: the first photo's index")
    ap.add_argument("--count", type=int, default=None, help="with --render-photos: how many (default: all)")
    ap.add_argument("--stemmed", action="store_true", help="with --render-photos: vessels on a stem, from their "
                    "own sequence (stemmed_vessel)")
    ap.add_argument("--init", default=None, metavar="WEIGHTS", help="train on from this segmenter's weights "
                    "(a second stage on further photos) instead of new ones")
    ap.add_argument("--stemmed-photos", nargs="+", default=None, metavar="FILE", help="photos of vessels on a "
                    "stem (--render-photos --stemmed), a share of every batch")
    args = ap.parse_args(argv)
    configure_threads(args.threads, args.device)
    settings = PROFILES["default"]
    if args.render_photos:
        set_mitsuba_variant("cpu", args.threads)
        count = settings.samples + settings.held_out - args.start if args.count is None else args.count
        save_photos(args.render_photos, make_photos(count, 0, settings.spp, True, args.start, args.stemmed))
        return
    if args.photos is None:
        set_mitsuba_variant("cpu", args.threads)
    init = read(args.init) if args.init else None
    meta = prepare(args.out or shipped_path(), seed=args.seed, progress=True, init=init,
                   data=load_photos(*args.photos) if args.photos else make_photos(
                       settings.samples + settings.held_out, 0, settings.spp, True),
                   stemmed=load_photos(*args.stemmed_photos) if args.stemmed_photos else None)
    print({k: meta[k] for k in ("held_out_mask_iou", "render_seconds", "train_seconds")})


if __name__ == "__main__":
    main()
