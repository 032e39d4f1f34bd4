"""The occupancy network's frame and training data: the regressor's samples (``ipm.learned.data``)
with inside/outside labels at points around each object, in the frame the input view fixes.

The frame: the anchor that :func:`ipm.problem.estimate_anchor` reads off the mask (the object's
ground point ``t`` and height ``s``), turned by the camera's azimuth about +y, so
``p_local = R_y(-azimuth) (p_world - t) / s``: the object stands on y = 0, about one unit high,
the camera towards +z. What one view cannot fix (depth, size) is then as the network learns it.
"""
from __future__ import annotations

import numpy as np

LOCAL_BOX = np.array([[-2.0, -0.1, -2.2], [2.0, 1.4, 1.6]])
"""The box of the local frame that the network learns and meshes. The training objects' extents
there (dishes and buildings, 25 and 40 samples): x -1.8 to 1.4, y 0 to 1.02, z -1.9 to 1.3 (the
anchor's height estimate is the visible top, its depth the front foot pushed back)."""
NEAR_SIGMA = (0.01, 0.05)
"""Standard deviations (local units) of the noise on the near-surface points, alternating."""
GIVEN_SHARE = 0.75
"""Share of training views whose class mask is given (``ipm.learned.data.make_dataset``'s)."""


def to_local(points: np.ndarray, anchor_t: np.ndarray, anchor_s: float, azimuth: float) -> np.ndarray:
    """World points (n, 3) in the anchor's frame: ``R_y(-azimuth) (p - anchor_t) / anchor_s``."""
    from ipm.pose import yaw_matrix

    return ((np.asarray(points, float) - anchor_t) / anchor_s) @ yaw_matrix(-azimuth).T


def to_world(points: np.ndarray, anchor_t: np.ndarray, anchor_s: float, azimuth: float) -> np.ndarray:
    """The inverse of :func:`to_local`: ``anchor_t + anchor_s R_y(azimuth) p``."""
    from ipm.pose import yaw_matrix

    return anchor_t + anchor_s * (np.asarray(points, float) @ yaw_matrix(azimuth).T)


def view_frame(mask: np.ndarray, c2w: np.ndarray, fov_x: float) -> tuple[np.ndarray, float, float]:
    """The frame one view fixes: anchor point, anchor height and camera azimuth (radians)."""
    from ipm.io.views import Views
    from ipm.learned.data import camera_azimuth
    from ipm.problem import estimate_anchor

    views = Views(fov_x=fov_x, width=mask.shape[1], height=mask.shape[0], c2w=np.asarray(c2w)[None],
                  masks=np.asarray(mask)[None])
    anchor_t, anchor_s = estimate_anchor(views)
    return anchor_t, float(anchor_s), camera_azimuth(c2w)


def occupancy_points(vertices: np.ndarray, faces: np.ndarray, rng: np.random.Generator, k: int,
                     box: np.ndarray = LOCAL_BOX) -> tuple[np.ndarray, np.ndarray]:
    """``k`` labelled points for one mesh: half uniform in ``box``, half on its surface moved by
    Gaussian noise (:data:`NEAR_SIGMA`); inside-ness by the volumetric metric's test
    (:func:`ipm.metrics.volume.occupancy`: per closed part, so overlapping solids stay inside)."""
    import trimesh

    from ipm.metrics.volume import occupancy

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    near = k // 2
    uniform = rng.uniform(box[0], box[1], (k - near, 3))
    surface, _ = trimesh.sample.sample_surface(mesh, near, seed=rng)
    sigma = np.where(np.arange(near) % 2 == 0, NEAR_SIGMA[0], NEAR_SIGMA[1])[:, None]
    points = np.concatenate([uniform, surface + sigma * rng.standard_normal((near, 3))])
    return points.astype(np.float32), occupancy(mesh, points)


def make_occupancy_dataset(gen, n: int, seed: int, k: int, progress: bool = False) -> dict:
    """``n`` training samples of ``gen``, drawn as :func:`ipm.learned.data.make_dataset` draws
    them (the same objects, views and network inputs for the same seed), each with ``k`` labelled
    points in its view's local frame: ``image``, ``cond``, ``points`` (n, k, 3), ``occupied``
    (n, k) and ``outside`` (how many objects leave :data:`LOCAL_BOX`)."""
    from tqdm import tqdm

    from ipm.learned.data import TRAIN_SEED_BASE, draw_sample, encode_view

    channels = 2 if gen.mask_class is not None else 1
    out = {"image": [], "cond": [], "points": [], "occupied": []}
    outside = 0
    seeds = np.random.SeedSequence(TRAIN_SEED_BASE + seed).spawn(n)
    for ss in tqdm(seeds, desc=f"occupancy samples {gen.name}", disable=not progress, leave=False):
        rng = np.random.default_rng(ss)
        sample = draw_sample(gen, rng)
        given = sample.class_mask if rng.random() < GIVEN_SHARE else None
        image, cond = encode_view(sample.mask, sample.c2w, sample.fov_x, given, channels)
        local = to_local(sample.vertices, *view_frame(sample.mask, sample.c2w, sample.fov_x))
        outside += int(np.any(local < LOCAL_BOX[0]) or np.any(local > LOCAL_BOX[1]))
        points, occupied = occupancy_points(local, sample.faces, rng, k)
        for name, value in (("image", image), ("cond", cond), ("points", points), ("occupied", occupied)):
            out[name].append(value)
    return {**{name: np.stack(v) for name, v in out.items()}, "outside": outside}
