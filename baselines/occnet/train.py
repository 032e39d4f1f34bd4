"""Training the occupancy network on a generator's samples, seeded, and scoring it on held-out ones.

``prepare(generator, out, profile=, seed=)`` is the baseline's preparation stage (``ipm prepare
occnet``, the workflow's ``prepare`` rule): it draws the samples (``baselines.occnet.data``),
trains with Adam on the binary cross-entropy of the points' occupancy, and writes the weights
with the held-out occupancy accuracy and IoU beside the constant (majority) prediction's.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Annotated

import numpy as np

from ipm.errors import UserError
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class OccnetSettings(Settings):
    """How much data and training a profile's occupancy network gets, and how it is meshed."""

    KIND = "occnet setting"

    samples: Annotated[int, at_least(1)] = 3000
    """Training samples drawn (``held_out`` more are drawn for the held-out score)."""
    held_out: Annotated[int, at_least(0)] = 200
    points: Annotated[int, at_least(2)] = 1024
    """Labelled points per sample (half uniform in the local box, half near the surface)."""
    batch: Annotated[int, at_least(1)] = 16
    """Samples per step."""
    batch_points: Annotated[int, at_least(1)] = 256
    """Points per sample per step, drawn from its ``points``."""
    steps: Annotated[int, at_least(1)] = 6000
    learning_rate: Annotated[float, Range(0.0, open_lo=True)] = 1e-3
    mesh_grid: Annotated[int, at_least(8)] = 160
    """Mesh grid cells along the local box's longest side."""
    level: Annotated[float, Range(0.0, 1.0, open_lo=True, open_hi=True)] = 0.5
    """Occupancy probability of the extracted surface."""
    keep: Annotated[float, Range(0.0, 1.0)] = 0.05
    """Mesh components whose volume is under this share of the largest one's are dropped."""


PROFILES = {
    "smoke": OccnetSettings(samples=48, held_out=16, points=256, batch=8, batch_points=128, steps=200,
                            learning_rate=3e-3, mesh_grid=32),
    "default": OccnetSettings(),
    "paper": OccnetSettings(samples=12000, held_out=500, steps=20000, batch=32, mesh_grid=256),
}
"""Budgets per workflow profile. ``default``: a few thousand samples, trained within about three
minutes per generator on one CPU thread (seed 0: dishes 159 s, buildings 203 s, beside two other
jobs on 2 cores; drawing and labelling the samples 63 s and 30 s more; ``docs/design``);
``paper``: four times the samples and a longer training; ``smoke`` runs in seconds (with a
higher learning rate: at 60 steps the cups' network still said "outside" everywhere)."""


def occnet_settings(profile: str, **overrides) -> OccnetSettings:
    """The named profile's settings with ``overrides`` (``UserError`` for unknown names or values)."""
    if profile not in PROFILES:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(PROFILES)})")
    return PROFILES[profile].updated(**overrides)


def held_out_scores(model, data: dict, majority: bool) -> dict:
    """Occupancy accuracy and IoU (probability over 0.5) on held-out samples' points, all of them
    and the uniform half alone, beside the constant prediction ``majority`` (the training labels'
    most frequent value)."""
    import equinox as eqx
    import jax

    run = eqx.filter_jit(lambda m, image, cond, points: jax.vmap(m)(image, cond, points))
    chunk, n = 16, len(data["image"])
    parts = []
    for i in range(0, n, chunk):
        sel = np.minimum(np.arange(i, i + chunk), n - 1)  # a full last chunk: one compilation
        parts.append(np.asarray(run(model, data["image"][sel], data["cond"][sel], data["points"][sel]))[: n - i])
    pred = np.concatenate(parts) > 0.0
    truth = data["occupied"]
    uniform = np.zeros(truth.shape[1], bool)
    uniform[: truth.shape[1] - truth.shape[1] // 2] = True  # the first points (occupancy_points orders them so)

    def iou(a, b):
        union = np.sum(a | b)
        return float(np.sum(a & b) / union) if union else 1.0

    return {"accuracy": float(np.mean(pred == truth)), "iou": iou(pred, truth),
            "box_accuracy": float(np.mean(pred[:, uniform] == truth[:, uniform])),
            "box_iou": iou(pred[:, uniform], truth[:, uniform]),
            "constant_accuracy": float(np.mean(truth == majority)),
            "constant_box_accuracy": float(np.mean(truth[:, uniform] == majority)),
            "inside_share": float(truth.mean())}


def fit(gen, settings: OccnetSettings, seed: int, progress: bool = False, data: dict | None = None):
    """Train an occupancy network for generator ``gen``: returns the model and its metadata (for
    :func:`baselines.occnet.network.save`)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import optax
    from tqdm import tqdm

    from baselines.occnet.data import LOCAL_BOX, make_occupancy_dataset
    from baselines.occnet.network import OccupancyNet
    from ipm.learned.data import N_COND, NET_RES

    t0 = time.perf_counter()
    if data is None:
        data = make_occupancy_dataset(gen, settings.samples + settings.held_out, seed, settings.points, progress)
    n = settings.samples
    arrays = {k: data[k] for k in ("image", "cond", "points", "occupied")}
    train = {k: v[:n] for k, v in arrays.items()}
    held = {k: v[n:] for k, v in arrays.items()}
    sample_s = time.perf_counter() - t0
    model = OccupancyNet(train["image"].shape[1], NET_RES, N_COND, jax.random.PRNGKey(seed))
    opt = optax.adam(optax.cosine_decay_schedule(settings.learning_rate, settings.steps, alpha=0.1))
    state = opt.init(eqx.filter(model, eqx.is_array))

    def loss_fn(model, image, cond, points, occupied):
        logits = jax.vmap(model)(image, cond, points)
        return jnp.mean(optax.sigmoid_binary_cross_entropy(logits, occupied))

    @eqx.filter_jit
    def step(model, state, image, cond, points, occupied):
        loss, grads = eqx.filter_value_and_grad(loss_fn)(model, image, cond, points, occupied)
        updates, state = opt.update(grads, state, model)
        return eqx.apply_updates(model, updates), state, loss

    rng = np.random.default_rng(seed)
    k = train["points"].shape[1]
    m = min(settings.batch_points, k)
    losses = []
    bar = tqdm(range(settings.steps), desc=f"train occnet {gen.name}", disable=not progress, leave=False)
    for _ in bar:
        idx = rng.integers(0, n, settings.batch)
        pick = np.argsort(rng.random((settings.batch, k)), axis=1)[:, :m]  # points without repeats per sample
        points = np.take_along_axis(train["points"][idx], pick[..., None], 1)
        occupied = np.take_along_axis(train["occupied"][idx], pick, 1).astype(np.float32)
        model, state, loss = step(model, state, jnp.asarray(train["image"][idx]), jnp.asarray(train["cond"][idx]),
                                  jnp.asarray(points), jnp.asarray(occupied))
        losses.append(float(loss))
        if len(losses) % 100 == 0:
            bar.set_postfix(loss=f"{np.mean(losses[-100:]):.3f}")
    train_s = time.perf_counter() - t0 - sample_s
    majority = bool(train["occupied"].mean() > 0.5)
    meta = {"generator": gen.name, "seed": seed, "settings": asdict(settings), "samples": n,
            "held_out_samples": int(len(held["image"])), "in_channels": int(train["image"].shape[1]),
            "res": NET_RES, "n_cond": N_COND, "box": LOCAL_BOX.tolist(),
            "objects_leaving_box": int(data.get("outside", 0)), "majority": majority,
            "final_loss": float(np.mean(losses[-50:])),
            "held_out": held_out_scores(model, held, majority) if len(held["image"]) else None,
            "sample_seconds": round(sample_s, 1), "train_seconds": round(train_s, 1)}
    return model, meta


def prepare(generator: str, out, profile: str = "default", seed: int = 0, progress: bool = False) -> dict:
    """The occupancy network's preparation stage: train ``generator``'s network with ``profile``'s
    budget (:data:`PROFILES`) from ``seed`` and write it to ``out``; returns the time and scores."""
    from baselines.occnet.network import save
    from ipm.generators import get_generator

    gen = get_generator(generator)
    model, meta = fit(gen, occnet_settings(profile), seed, progress)
    save(model, out, meta)
    return summary(meta)


def summary(meta: dict) -> dict:
    """The facts of a training that a run's info and the preparation stage report."""
    keys = ("samples", "held_out_samples", "held_out", "final_loss", "sample_seconds", "train_seconds")
    return {"seconds": meta["sample_seconds"] + meta["train_seconds"], **{k: meta[k] for k in keys if k in meta}}
