"""The regressor's proposals for a view: ``z`` vectors of a problem (``ipm.problem``), best first.

Weights come from the workflow's preparation stage (``prepared``) or, where none is given, from
the set shipped with the package (``ipm/learned/weights/GENERATOR.json``, made by the same
code: ``python -m ipm.learned.ship``).
"""
from __future__ import annotations

import itertools
from functools import lru_cache
from pathlib import Path

import numpy as np

from ipm.errors import UserError

SHIPPED = Path(__file__).parent / "weights"
"""Folder of the weights shipped with the package, one file per generator."""


def weights_path(generator: str, prepared: str | Path | None = None) -> Path:
    """The weights to use: ``prepared`` if given, else the shipped file (``UserError`` if none)."""
    if prepared is not None:
        return Path(prepared)
    path = SHIPPED / f"{generator}.json"
    if not path.exists():
        raise UserError(f"no learned weights for {generator!r}: make them with "
                        f"'ipm prepare --method learned --generator {generator} --out FILE' and pass --prepared FILE")
    return path


def has_weights(generator: str, prepared: str | Path | None = None) -> bool:
    """Whether :func:`weights_path` has weights for ``generator`` (``prepared``, else shipped)."""
    return prepared is not None or (SHIPPED / f"{generator}.json").exists()


@lru_cache(maxsize=4)
def _load(path: str, generator: str):
    from ipm.learned.network import load

    return load(path, expect_generator=generator)


def load_regressor(generator: str, prepared: str | Path | None = None):
    """The regressor and its metadata for ``generator`` (kept in memory for the next call)."""
    return _load(str(weights_path(generator, prepared)), generator)


def discrete_choices(probs: list[np.ndarray], k: int) -> list[tuple[tuple[int, ...], float]]:
    """The ``k`` most probable joint choices of independent per-parameter class distributions
    (class indices, probability), best first: a beam over the parameters."""
    beam = [((), 1.0)]
    for p in probs:
        order = np.argsort(p)[::-1][:k]
        beam = sorted(((c + (int(j),), q * float(p[j])) for (c, q), j in itertools.product(beam, order)),
                      key=lambda t: -t[1])[:k]
    return beam


def propose(problem, views, k: int = 1, prepared: str | Path | None = None) -> list[np.ndarray]:
    """Up to ``k`` starts ``z`` for ``problem`` from the first view, best first: the predicted
    continuous parameters and pose with each of the ``k`` most probable joints of the discrete
    parameters. Known cameras only (an unknown camera's genes are not proposed)."""
    from ipm.learned.data import encode_view
    from ipm.learned.train import predict
    from ipm.search.objective import class_masks

    if problem.camera is not None:
        raise UserError("the learned proposal needs the view's camera")
    gen = problem.generator
    model, meta = load_regressor(gen.name, prepared)
    spec = gen.spec
    if meta["continuous"] != [n for n, d in zip(spec.names, spec.discrete) if not d] or \
            meta["discrete"] != [n for n, d in zip(spec.names, spec.discrete) if d]:
        raise UserError(f"the learned weights for {gen.name!r} were made for other parameters; make them again")
    found = class_masks(gen, views)
    image, cond = encode_view(views.masks[0], views.c2w[0], views.fov_x, None if found is None else found[0][0],
                              meta["in_channels"])
    out = predict(model, image[None], cond[None])
    pose = out["pose"][0] * np.asarray(meta["pose_std"]) + np.asarray(meta["pose_mean"])
    yaw = float(np.arctan2(out["yaw"][0, 1], out["yaw"][0, 0]))
    starts = []
    for levels, _ in discrete_choices([p[0] for p in out["probs"]], k):
        u = np.zeros(len(spec))
        u[~spec.discrete] = out["u"][0]
        x = spec.from_unit(u)
        x[spec.discrete] = spec.lower[spec.discrete] + np.asarray(levels, float)
        starts.append(start_z(problem, spec.to_unit(spec.clip(x)), yaw, pose, views.c2w[0]))
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
    return problem.clip(np.concatenate([u, [relative_yaw + azimuth, 0.0, 0.0, offset[0], 0.0, offset[2], log_scale]]))
