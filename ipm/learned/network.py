"""The regressor: a small CNN over the view's crop, conditioned on the camera, that predicts a
generator's parameters and the object's pose in the search's coordinates (``ipm.learned.data``).

Heads: the continuous unit-cube parameters (sigmoid), one set of logits per discrete parameter
(its values as classes), the yaw relative to the camera as a unit vector, and the pose (two
offsets from the anchor and the log height ratio). Equinox modules; weights are stored with
their shapes and the generator's layout in one JSON file (:func:`save`, :func:`load`).
"""
from __future__ import annotations

import base64
import binascii
import io
import json
from pathlib import Path
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ipm.errors import UserError

CHANNELS = (16, 32, 64, 64)
"""Convolution widths, each a 3 x 3 stride-2 layer: 64 px in, 4 x 4 out."""
HIDDEN = 256
"""Width of the two fully connected layers after the convolutions."""
FORMAT = "ipm-learned-regressor/1"


class Regressor(eqx.Module):
    """Image (C, R, R) and camera numbers (N_COND,) -> (unit params, discrete logits, yaw, pose; the
    pose with the camera's pitch and lens for the camera-hidden variant, ``n_pose`` 5)."""

    convs: list
    fc: list
    head: eqx.nn.Linear
    n_cont: int = eqx.field(static=True)
    levels: tuple = eqx.field(static=True)
    n_pose: int = eqx.field(static=True)

    def __init__(self, in_channels: int, res: int, n_cond: int, n_cont: int, levels: tuple[int, ...], key,
                 n_pose: int = 3):
        keys = jax.random.split(key, len(CHANNELS) + 3)
        self.convs = conv_stack(in_channels, keys[:len(CHANNELS)])
        flat = conv_features_size(res)
        self.fc = [eqx.nn.Linear(flat + n_cond, HIDDEN, key=keys[-3]), eqx.nn.Linear(HIDDEN, HIDDEN, key=keys[-2])]
        self.n_cont, self.levels, self.n_pose = n_cont, tuple(int(v) for v in levels), int(n_pose)
        self.head = eqx.nn.Linear(HIDDEN, n_cont + sum(self.levels) + 2 + self.n_pose, key=keys[-1])

    def __call__(self, image, cond):
        h = jnp.concatenate([conv_features(self.convs, image), cond])
        for layer in self.fc:
            h = jax.nn.relu(layer(h))
        out = self.head(h)
        cont = jax.nn.sigmoid(out[: self.n_cont])
        logits = out[self.n_cont: self.n_cont + sum(self.levels)]
        yaw = out[-self.n_pose - 2: -self.n_pose]
        yaw = yaw / jnp.sqrt(jnp.sum(yaw**2) + 1e-6)
        return cont, logits, yaw, out[-self.n_pose:]


def conv_stack(in_channels: int, keys) -> list:
    """The image encoder's layers: one 3 x 3 stride-2 convolution per width of :data:`CHANNELS`."""
    widths = (in_channels,) + CHANNELS
    return [eqx.nn.Conv2d(a, b, 3, stride=2, padding=1, key=k) for a, b, k in zip(widths[:-1], widths[1:], keys)]


def conv_features_size(res: int) -> int:
    """Length of :func:`conv_features` for a ``res`` x ``res`` image."""
    return CHANNELS[-1] * (res // 2 ** len(CHANNELS)) ** 2


def conv_features(convs: list, image):
    """The flattened features of ``image`` (C, R, R) after the layers of :func:`conv_stack` (ReLU each)."""
    h = image
    for conv in convs:
        h = jax.nn.relu(conv(h))
    return h.ravel()


def split_logits(logits, levels: tuple[int, ...]) -> list:
    """The per-parameter logits of the concatenated discrete head."""
    edges = np.cumsum((0,) + tuple(levels))
    return [logits[..., a:b] for a, b in zip(edges[:-1], edges[1:])]


def save(model: eqx.Module, path: str | Path, meta: dict, fmt: str = FORMAT) -> None:
    """Write the model (its weights rounded to float16, base64: half the size, proposals the same to
    a few parts in ten thousand) and ``meta`` (the generator, the layout the weights need, training
    facts) into one JSON file marked ``fmt``, atomically."""
    from ipm.io.atomic import write_json

    buf = io.BytesIO()
    eqx.tree_serialise_leaves(buf, _cast(model, jnp.float16))
    write_json(path, {"format": fmt, **meta, "weights": base64.b64encode(buf.getvalue()).decode("ascii")})


def load(path: str | Path, expect_generator: str | None = None) -> tuple[Regressor, dict]:
    """The model and its metadata from a file written by :func:`save` (``UserError`` for a missing
    or malformed file, or one made for another generator)."""
    return load_model(path, FORMAT, "a learned regressor's", lambda r: Regressor(
        r["in_channels"], r["res"], r["n_cond"], r["n_cont"], tuple(r["levels"]), jax.random.PRNGKey(0),
        len(r["pose_mean"])),
        expect_generator)


def load_model(path: str | Path, fmt: str, what: str, skeleton: Callable[[dict], eqx.Module],
               expect_generator: str | None = None) -> tuple[eqx.Module, dict]:
    """A model saved by :func:`save` as ``fmt``, rebuilt by ``skeleton(record)`` and filled with the
    file's weights, and its metadata; ``UserError`` naming ``what`` the file should hold for a
    missing, malformed or foreign file, or one made for another generator than ``expect_generator``."""
    path = Path(path)
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(f"no learned weights at {path}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, IsADirectoryError) as exc:
        raise UserError(f"malformed learned weights {path}: {exc}") from None
    if not isinstance(record, dict) or record.get("format") != fmt:
        raise UserError(f"{path} is not {what} weights (format {fmt})")
    if expect_generator is not None and record.get("generator") != expect_generator:
        raise UserError(f"{path} holds weights for {record.get('generator')!r}, not {expect_generator!r}")
    try:
        like = jax.tree_util.tree_map(lambda a: np.zeros(a.shape, np.float16) if _floating(a) else a,
                                      eqx.filter_eval_shape(skeleton, record))
        model = eqx.tree_deserialise_leaves(io.BytesIO(base64.b64decode(record["weights"], validate=True)), like)
    except (KeyError, TypeError, ValueError, RuntimeError, EOFError, binascii.Error) as exc:
        raise UserError(f"malformed learned weights {path}: {type(exc).__name__}: {exc}") from None
    meta = {k: v for k, v in record.items() if k != "weights"}
    return jax.tree_util.tree_map(lambda a: jnp.asarray(np.asarray(a, np.float32)) if _floating(a) else a, model), meta


def _floating(a) -> bool:
    """Whether ``a`` is a floating-point array or array shape (the leaves saved as float16)."""
    return hasattr(a, "shape") and hasattr(a, "dtype") and np.issubdtype(a.dtype, np.floating)


def _cast(model: eqx.Module, dtype) -> eqx.Module:
    """The model with every floating-point array as ``dtype``."""
    return jax.tree_util.tree_map(lambda a: a.astype(dtype) if _floating(a) else a, model)
