"""Training the regressor on a generator's own samples, seeded, and scoring it on held-out ones.

``prepare(generator, out, profile=, seed=)`` is the learned methods' preparation stage
(``ipm prepare --method learned``, the workflow's ``prepare`` rule): it draws the samples
(``ipm.learned.data``), trains with Adam, and writes the weights with the held-out errors beside
the mean prediction's (what a network that learned nothing scores).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Annotated

import numpy as np

from ipm.errors import UserError
from ipm.settings import Range, Settings, at_least


@dataclass(frozen=True)
class TrainSettings(Settings):
    """How much data and training a profile's regressor gets."""

    KIND = "learned setting"
    samples: Annotated[int, at_least(1)] = 6000
    """Training samples drawn (``held_out`` more are drawn for the held-out score)."""
    held_out: Annotated[int, at_least(0)] = 500
    steps: Annotated[int, at_least(1)] = 4000
    batch: Annotated[int, at_least(1)] = 64
    learning_rate: Annotated[float, Range(1e-6, 1.0)] = 1e-3
    pose_weight: Annotated[float, at_least(0.0)] = 1.0
    """Weight of the pose terms (yaw and offsets) against the parameters' in the loss."""


TRAIN_PROFILES = {
    "smoke": TrainSettings(samples=96, held_out=32, steps=40, batch=16),
    "default": TrainSettings(),
    "paper": TrainSettings(samples=20000, held_out=1000, steps=12000),
}
"""Training budgets per workflow profile (``paper``: as many samples per generator as DI-PCG's)."""


def train_settings(profile: str) -> TrainSettings:
    if profile not in TRAIN_PROFILES:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(TRAIN_PROFILES)})")
    return TRAIN_PROFILES[profile]


def _loss_fn(levels, pose_weight):
    import jax
    import jax.numpy as jnp

    from ipm.learned.network import split_logits

    def loss(model, batch):
        cont, logits, yaw, pose = jax.vmap(model)(batch["image"], batch["cond"])
        w = batch["active"]
        l_cont = jnp.sum(w * (cont - batch["u"]) ** 2) / jnp.maximum(jnp.sum(w), 1.0)
        l_disc = 0.0
        for i, lg in enumerate(split_logits(logits, levels)):
            l_disc += -jnp.mean(jnp.take_along_axis(jax.nn.log_softmax(lg), batch["levels"][:, i:i + 1], 1))
        l_disc = l_disc / max(len(levels), 1)
        l_yaw = jnp.sum(batch["yaw_on"] * jnp.sum((yaw - batch["yaw"]) ** 2, 1)) / jnp.maximum(jnp.sum(batch["yaw_on"]), 1.0)
        l_pose = jnp.mean((pose - batch["pose"]) ** 2)
        return 10.0 * l_cont + l_disc + pose_weight * (l_yaw + l_pose)

    return loss


@lru_cache(maxsize=1)
def _batched():
    """The model over a batch, compiled once per input shape (one function for every call)."""
    import equinox as eqx
    import jax

    return eqx.filter_jit(lambda m, a, b: jax.vmap(m)(a, b))


def predict(model, image: np.ndarray, cond: np.ndarray, chunk: int = 256) -> dict:
    """The model's outputs for a batch of inputs, as numpy: ``u``, ``probs`` (per discrete
    parameter), ``yaw`` (unit vectors) and ``pose`` (standardised as trained)."""
    import jax
    import jax.numpy as jnp

    from ipm.learned.network import split_logits

    fn = _batched()
    parts = [fn(model, jnp.asarray(image[i:i + chunk]), jnp.asarray(cond[i:i + chunk]))
             for i in range(0, len(image), chunk)]
    cont, logits, yaw, pose = (np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(4))
    probs = [np.asarray(jax.nn.softmax(jnp.asarray(lg), -1)) for lg in split_logits(logits, model.levels)]
    return {"u": cont, "probs": probs, "yaw": yaw, "pose": pose}


def held_out_errors(model, data: dict, pose_mean: np.ndarray, pose_std: np.ndarray) -> dict:
    """Errors on held-out samples, the network's beside the mean prediction's (the training mean):
    mean absolute unit-parameter error over the parameters that shape each object, discrete
    accuracy, yaw error (degrees, where it matters), and the pose's mean absolute error."""
    out = predict(model, data["image"], data["cond"])
    w = data["active"]
    err = np.sum(w * np.abs(out["u"] - data["u"])) / max(w.sum(), 1.0)
    acc = float(np.mean([np.mean(p.argmax(1) == data["levels"][:, i]) for i, p in enumerate(out["probs"])])) \
        if out["probs"] else 1.0
    on = data["yaw_on"] > 0
    yaw_err = np.degrees(np.abs(np.angle((out["yaw"][:, 0] + 1j * out["yaw"][:, 1])
                                         * (data["yaw"][:, 0] - 1j * data["yaw"][:, 1]))))
    pose = out["pose"] * pose_std + pose_mean
    return {"param_mae": float(err), "discrete_accuracy": acc,
            "yaw_error_deg": float(np.median(yaw_err[on])) if on.any() else None,
            "pose_mae": np.mean(np.abs(pose - data["pose"]), 0).round(4).tolist(), **camera_errors(pose, data["pose"])}


def camera_errors(pose: np.ndarray, truth: np.ndarray) -> dict:
    """The camera-hidden variant's median pitch error (degrees) and field-of-view error (relative,
    horizontal) for predicted and true pose rows; nothing for the known-camera variant."""
    if pose.shape[1] < 5:
        return {}
    fov = lambda p: 2 * np.arctan(np.exp(p[:, 4]))  # noqa: E731
    return {"pitch_error_deg": float(np.median(np.degrees(np.abs(pose[:, 3] - truth[:, 3])))),
            "fov_error_rel": float(np.median(np.abs(fov(pose) / fov(truth) - 1)))}


def mean_prediction_errors(train: dict, data: dict) -> dict:
    """The same errors for the prediction that ignores the image: the training set's mean
    parameters (over the objects they shape), most frequent discrete values, and mean pose."""
    w = train["active"]
    mean_u = np.sum(w * train["u"], 0) / np.maximum(w.sum(0), 1.0)
    wd = data["active"]
    err = np.sum(wd * np.abs(mean_u[None] - data["u"])) / max(wd.sum(), 1.0)
    levels = train["levels"]
    acc = float(np.mean([np.mean(data["levels"][:, i] == np.bincount(levels[:, i]).argmax())
                         for i in range(levels.shape[1])])) if levels.shape[1] else 1.0
    mean_pose = np.broadcast_to(train["pose"].mean(0), data["pose"].shape)
    return {"param_mae": float(err), "discrete_accuracy": acc, "yaw_error_deg": 90.0,
            "pose_mae": np.mean(np.abs(mean_pose - data["pose"]), 0).round(4).tolist(),
            **camera_errors(mean_pose, data["pose"])}


def fit(gen, settings: TrainSettings, seed: int, progress: bool = False, data: dict | None = None,
        camera_hidden: bool = False):
    """Train a regressor for generator ``gen`` (``camera_hidden``: the photo variant, which proposes
    the camera too, ``ipm.learned.data.make_dataset``): the model and its metadata (for
    :func:`ipm.learned.network.save`)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import optax
    from tqdm import tqdm

    from ipm.learned.data import N_COND, NET_RES, make_dataset
    from ipm.learned.network import Regressor

    t0 = time.perf_counter()
    if data is None:
        data = make_dataset(gen, settings.samples + settings.held_out, seed, progress, camera_hidden)
    n = settings.samples
    train = {k: v[:n] for k, v in data.items()}
    held = {k: v[n:] for k, v in data.items()}
    sample_s = time.perf_counter() - t0
    pose_mean, pose_std = train["pose"].mean(0), train["pose"].std(0) + 1e-3
    spec = gen.spec
    levels = tuple(int(v) for v in (spec.upper - spec.lower + 1)[spec.discrete])
    key = jax.random.PRNGKey(seed)
    model = Regressor(train["image"].shape[1], NET_RES, N_COND, int((~spec.discrete).sum()), levels, key,
                      n_pose=train["pose"].shape[1])
    schedule = optax.cosine_decay_schedule(settings.learning_rate, settings.steps)
    opt = optax.adam(schedule)
    state = opt.init(eqx.filter(model, eqx.is_array))
    loss_fn = _loss_fn(levels, settings.pose_weight)

    @eqx.filter_jit
    def step(model, state, batch):
        loss, grads = eqx.filter_value_and_grad(loss_fn)(model, batch)
        updates, state = opt.update(grads, state, model)
        return eqx.apply_updates(model, updates), state, loss

    standardised = {**train, "pose": (train["pose"] - pose_mean) / pose_std}
    rng = np.random.default_rng(seed)
    losses = []
    bar = tqdm(range(settings.steps), desc=f"train {gen.name}", disable=not progress, leave=False)
    for _ in bar:
        idx = rng.integers(0, n, settings.batch)
        batch = {k: jnp.asarray(v[idx]) for k, v in standardised.items()}
        model, state, loss = step(model, state, batch)
        losses.append(float(loss))
        if len(losses) % 100 == 0:
            bar.set_postfix(loss=f"{np.mean(losses[-100:]):.3f}")
    train_s = time.perf_counter() - t0 - sample_s
    meta = {"generator": gen.name, "seed": seed, "settings": asdict(settings), "camera_hidden": camera_hidden,
            "in_channels": int(train["image"].shape[1]), "res": NET_RES, "n_cond": N_COND,
            "n_cont": int((~spec.discrete).sum()), "levels": list(levels),
            "continuous": [nm for nm, d in zip(spec.names, spec.discrete) if not d],
            "discrete": [nm for nm, d in zip(spec.names, spec.discrete) if d],
            "pose_mean": pose_mean.tolist(), "pose_std": pose_std.tolist(),
            "final_loss": float(np.mean(losses[-50:])),
            "held_out": held_out_errors(model, held, pose_mean, pose_std) if len(held["u"]) else None,
            "mean_prediction": mean_prediction_errors(train, held) if len(held["u"]) else None,
            "sample_seconds": round(sample_s, 1), "train_seconds": round(train_s, 1)}
    return model, meta


def prepare(generator: str, out, profile: str = "default", seed: int = 0, progress: bool = False,
            camera_hidden: bool = False) -> dict:
    """The learned methods' preparation stage: train ``generator``'s regressor with ``profile``'s
    budget (:data:`TRAIN_PROFILES`) from ``seed`` and write it to ``out`` (``camera_hidden``: the
    photo variant, :func:`prepare_photo`)."""
    from ipm.generators import get_generator
    from ipm.learned.network import save

    gen = get_generator(generator)
    if not gen.differentiable:
        raise UserError(f"the learned regressor needs a generator with a parameter vector it can regress; "
                        f"{generator!r} is searched by the GA path")
    model, meta = fit(gen, train_settings(profile), seed, progress, camera_hidden=camera_hidden)
    save(model, out, meta)
    return {"seconds": meta["sample_seconds"] + meta["train_seconds"],
            **{k: v for k, v in meta.items() if k in ("held_out", "mean_prediction", "sample_seconds", "train_seconds")}}


def prepare_photo(generator: str, out, profile: str = "default", seed: int = 0, progress: bool = False) -> dict:
    """The preparation stage of the camera-hidden variant (a photo's: its pitch and field of view
    proposed too, ``ipm prepare --method learned_photo``)."""
    return prepare(generator, out, profile, seed, progress, camera_hidden=True)
