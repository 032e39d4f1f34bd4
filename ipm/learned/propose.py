"""The regressor's proposals for a view: ``z`` vectors of a problem (``ipm.problem``), best first.

Weights come from the workflow's preparation stage (``prepared``) or, where none is given, from
the set shipped with the package (``ipm/learned/weights/GENERATOR.json``, made by the same
code: ``python -m ipm.ship``).
"""
from __future__ import annotations

import itertools
from functools import lru_cache
from pathlib import Path

import numpy as np

from ipm.errors import UserError

def shipped_path(generator: str, camera_hidden: bool = False) -> Path:
    """The shipped weights' file of ``generator``'s regressor (``camera_hidden``: the photo variant's)."""
    from ipm.methods import METHODS

    return METHODS["learned_photo" if camera_hidden else "learned"].shipped_path(generator)


def weights_path(generator: str, prepared: str | Path | None = None, camera_hidden: bool = False) -> Path:
    """The weights to use: ``prepared`` if given, else the shipped file (``UserError`` if none)."""
    if prepared is not None:
        return Path(prepared)
    path = shipped_path(generator, camera_hidden)
    if not path.exists():
        method = "learned_photo" if camera_hidden else "learned"
        raise UserError(f"no learned weights for {generator!r}: make them with "
                        f"'ipm prepare --method {method} --generator {generator} --out FILE' and pass --prepared FILE")
    return path


def has_weights(generator: str, prepared: str | Path | None = None, camera_hidden: bool = False) -> bool:
    """Whether :func:`weights_path` has weights for ``generator`` (``prepared``, else shipped)."""
    return prepared is not None or shipped_path(generator, camera_hidden).exists()


@lru_cache(maxsize=4)
def _load(path: str, generator: str):
    from ipm.learned.network import load

    return load(path, expect_generator=generator)


def load_regressor(generator: str, prepared: str | Path | None = None, camera_hidden: bool = False):
    """The regressor and its metadata for ``generator`` (kept in memory for the next call);
    ``camera_hidden``: the photo variant's (``UserError`` if the file holds the other variant)."""
    path = weights_path(generator, prepared, camera_hidden)
    model, meta = _load(str(path), generator)
    if bool(meta.get("camera_hidden", False)) != camera_hidden:
        want, has = ("camera-hidden", "known-camera") if camera_hidden else ("known-camera", "camera-hidden")
        raise UserError(f"{path} holds the {has} regressor, not the {want} one (ipm prepare --method "
                        f"{'learned_photo' if camera_hidden else 'learned'})")
    spec = _spec(generator)
    if meta["continuous"] != [n for n, d in zip(spec.names, spec.discrete) if not d] or \
            meta["discrete"] != [n for n, d in zip(spec.names, spec.discrete) if d]:
        raise UserError(f"the learned weights for {generator!r} were made for other parameters; make them again")
    return model, meta


def _spec(generator: str):
    from ipm.generators import get_generator

    return get_generator(generator).spec


def discrete_choices(probs: list[np.ndarray], k: int) -> list[tuple[tuple[int, ...], float]]:
    """The ``k`` most probable joint choices of independent per-parameter class distributions
    (class indices, probability), best first: a beam over the parameters."""
    beam = [((), 1.0)]
    for p in probs:
        order = np.argsort(p)[::-1][:k]
        beam = sorted(((c + (int(j),), q * float(p[j])) for (c, q), j in itertools.product(beam, order)),
                      key=lambda t: -t[1])[:k]
    return beam


def read_view(generator: str, views, prepared: str | Path | None = None, camera_hidden: bool = False) -> dict:
    """The regressor's outputs for the first view of ``views`` (``predict``'s, for one), the pose
    rows back in their units (``pose``); with ``camera_hidden`` the view's camera is not read."""
    from ipm.generators import get_generator
    from ipm.learned.data import encode_view
    from ipm.learned.train import predict
    from ipm.search.objective import class_masks

    model, meta = load_regressor(generator, prepared, camera_hidden)
    found = class_masks(get_generator(generator), views)
    seen = (None, None) if camera_hidden else (views.c2w[0], views.fov_x)
    image, cond = encode_view(views.masks[0], *seen, None if found is None else found[0][0], meta["in_channels"])
    out = predict(model, image[None], cond[None])
    return {**out, "pose": out["pose"][0] * np.asarray(meta["pose_std"]) + np.asarray(meta["pose_mean"])}


def propose_camera(generator: str, views, prepared: str | Path | None = None) -> tuple[float, float]:
    """The camera-hidden regressor's pitch (radians below the horizon) and horizontal field of view
    (radians) for a photo's mask (the first of ``views``; its camera, if any, is not read)."""
    pose = read_view(generator, views, prepared, camera_hidden=True)["pose"]
    return float(pose[3]), float(2.0 * np.arctan(np.exp(pose[4])))


def choices_apart(probs: list[np.ndarray], names: list[str],
                  apart: dict[str, int]) -> list[tuple[tuple[int, ...], float]]:
    """For every combination of values of the discrete parameters ``apart`` names (by ``names``)
    other than the one it gives, the most probable joint choice with it (as :func:`discrete_choices`),
    most probable first."""
    fixed = [names.index(n) for n in apart]
    out = []
    for values in itertools.product(*(range(len(probs[i])) for i in fixed)):
        if values == tuple(apart.values()):
            continue
        forced = [np.eye(len(p))[values[fixed.index(i)]] if i in fixed else p for i, p in enumerate(probs)]
        (levels, _), = discrete_choices(forced, 1)
        out.append((levels, float(np.prod([probs[i][v] for i, v in enumerate(levels)]))))
    return sorted(out, key=lambda t: -t[1])


def propose(problem, views, k: int = 1, prepared: str | Path | None = None,
            apart: dict[str, int] | None = None) -> list[np.ndarray]:
    """Up to ``k`` starts ``z`` for ``problem`` from the first view, best first: the predicted
    continuous parameters and pose with each of the ``k`` most probable joints of the discrete
    parameters; with ``apart`` (discrete parameters by name, each with a value index), instead
    :func:`choices_apart`'s joints. An unknown camera (a photo's) is read by the camera-hidden
    variant, its genes at the render camera's (whose pitch and lens :func:`propose_camera` can have set)."""
    gen = problem.generator
    spec = gen.spec
    out = read_view(gen.name, views, prepared, camera_hidden=problem.camera is not None)
    yaw = float(np.arctan2(out["yaw"][0, 1], out["yaw"][0, 0]))
    probs = [p[0] for p in out["probs"]]
    names = [n for n, d in zip(spec.names, spec.discrete) if d]
    starts = []
    for levels, _ in (choices_apart(probs, names, apart) if apart else discrete_choices(probs, k)):
        u = np.zeros(len(spec))
        u[~spec.discrete] = out["u"][0]
        x = spec.from_unit(u)
        x[spec.discrete] = spec.lower[spec.discrete] + np.asarray(levels, float)
        starts.append(start_z(problem, spec.to_unit(spec.clip(x)), yaw, out["pose"][:3], views.c2w[0]))
    return starts


def start_z(problem, u: np.ndarray, relative_yaw: float, pose: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """The problem's ``z`` for unit parameters ``u``, a yaw relative to the camera ``c2w``'s azimuth,
    and the pose as ``ipm.learned.data.targets`` gives it (offsets from the anchor in the camera's
    horizontal frame, log of the object's height over the anchor's)."""
    from ipm.learned.data import camera_azimuth
    from ipm.pose import yaw_matrix

    azimuth = camera_azimuth(c2w)
    offset = yaw_matrix(azimuth) @ np.array([pose[0], 0.0, pose[1]])
    log_scale = pose[2] - np.log(problem.object_height(u))
    genes = [] if problem.camera is None else [problem.camera.pitch0, 0.0, 0.0]  # the render camera: the anchor's
    return problem.clip(np.concatenate([u, [relative_yaw + azimuth, 0.0, 0.0, offset[0], 0.0, offset[2], log_scale],
                                        genes]))
