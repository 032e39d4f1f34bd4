"""Training samples for the learned proposals: a generator's random objects at random poses, seen
by a random camera from the benchmark's range, as the network sees an input view.

Every sample is drawn from its own seed, ``TRAIN_SEED_BASE + seed`` spawned per index, a range no
case's sampler seed reaches (``ipm.cases``: 1001-5046), so no test object is ever trained on. An
input view becomes the network's input by :func:`encode_view`, the same function at training and
at inference: the mask (and the generator's class mask, windows for buildings) cropped square
around the object and resampled to ``NET_RES``, and the camera as a few numbers (pitch, lens,
where the crop sits in the image). The targets are the search's own coordinates
(``ipm.problem``): unit-cube parameters and the pose relative to the anchor that
:func:`ipm.problem.estimate_anchor` reads off the same mask, turned into the camera's frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TRAIN_SEED_BASE = 10_000_000
"""Training samples draw from seeds ``TRAIN_SEED_BASE + seed`` (spawned per sample)."""
RENDER_RES = 128
"""Width and height (pixels) of a training sample's rendered view."""
NET_RES = 64
"""Width and height of the network's input crop."""
CROP_MARGIN = 1.15
"""The crop's side over the mask's larger bounding-box side."""
ELEVATIONS = (5.0, 45.0)
"""Camera elevations of the training views (degrees): the cases' 10-35 and some room either side."""
PHOTO_ELEVATIONS = (2.0, 60.0)
"""Camera elevations of the camera-hidden variant's views (degrees): a photo's, level to steeply
above (``ipm.photo.PITCH_PRIOR``)."""
FOV_DEFAULT_SHARE = 0.5
"""Share of training views at the benchmark's lens (``ipm.synth.FOV_X``); the rest draw theirs
from ``ipm.cases.FOV_RANGE``, as photos have them."""
N_COND = 6
"""Camera numbers beside the image: elevation, tan(fov / 2), crop centre (x, y) and side in
tangent units, and whether the class mask was given. With the camera hidden (a photo's),
elevation and lens are 0 and the tangent units those of :data:`ipm.photo.DEFAULT_FOV`."""


@dataclass
class Sample:
    """One training object and the view of it."""

    x: np.ndarray
    """Physical parameters."""
    yaw: float
    scale: float
    translation: np.ndarray
    c2w: np.ndarray
    fov_x: float
    vertices: np.ndarray
    """World-frame vertices (the generator's mesh at the sample's pose)."""
    faces: np.ndarray
    labels: np.ndarray
    mask: np.ndarray
    """(RENDER_RES, RENDER_RES) float32 silhouette."""
    class_mask: np.ndarray | None
    """The generator's class mask (``Generator.mask_class``), None where it has none."""


def sample_lod(gen) -> int:
    """Level of detail of the training meshes: the first that shows the class mask's parts, at least 1."""
    return max(1, gen.min_fit_lod)


def draw_sample(gen, rng: np.random.Generator, res: int = RENDER_RES, elevations=ELEVATIONS,
                x: np.ndarray | None = None) -> Sample:
    """A random object of ``gen``'s family (``Generator.sample``; ``x``: these parameters instead) at a
    random pose (as the test cases: any yaw, offsets up to 0.1, scale 0.85-1.15) seen from a random
    orbit camera (any azimuth, elevation in ``elevations`` (degrees), lens the benchmark's or a
    photo's), framed as the cases are."""
    from ipm.cases import FOV_RANGE
    from ipm.pose import yaw_matrix
    from ipm.synth import FOV_X, view_cameras

    x = gen.sample(rng) if x is None else x
    yaw = float(rng.uniform(0.0, 2 * np.pi))
    translation = np.array([rng.uniform(-0.1, 0.1), 0.0, rng.uniform(-0.1, 0.1)])
    scale = float(rng.uniform(0.85, 1.15))
    azimuth, elevation = float(rng.uniform(-180.0, 180.0)), float(rng.uniform(*elevations))
    if rng.random() < FOV_DEFAULT_SHARE:
        fov = FOV_X
    else:
        lo, hi = np.log(np.tan(np.radians(FOV_RANGE) / 2))
        fov = float(2 * np.arctan(np.exp(rng.uniform(lo, hi))))
    mesh = gen.mesh(x, sample_lod(gen), uv=False)  # a silhouette needs no texture charts
    v = scale * mesh.vertices @ yaw_matrix(yaw).T + translation
    lo, hi = v.min(0), v.max(0)
    c2w = view_cameras((lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2), 1, azimuth, elevation, "hemi", fov)[0]
    hit = cast_labels(v, mesh.faces, c2w, fov, res)
    mask = (hit >= 0).astype(np.float32)
    class_mask = None
    if gen.mask_class is not None:
        value = gen.semantic_labels[gen.mask_class]
        part_class = np.asarray(gen.part_semantic)[mesh.labels]
        class_mask = np.where(hit >= 0, part_class[np.maximum(hit, 0)] == value, False).astype(np.float32)
    return Sample(x, yaw, scale, translation, c2w, fov, v, mesh.faces, mesh.labels, mask, class_mask)


def cast_labels(vertices: np.ndarray, faces: np.ndarray, c2w: np.ndarray, fov_x: float, res: int) -> np.ndarray:
    """The triangle each pixel's centre ray hits first, -1 for none, (res, res), row 0 at the top."""
    from ipm.metrics.silhouette import camera_rays, open3d, raycasting_scene
    from ipm.runtime import thread_count

    import trimesh

    origins, dirs = camera_rays([c2w], res, float(np.degrees(fov_x)))
    rays = np.concatenate([np.broadcast_to(origins[:, None], dirs.shape), dirs], -1).astype(np.float32)
    scene = raycasting_scene(trimesh.Trimesh(vertices, faces, process=False))
    ids = scene.cast_rays(open3d().core.Tensor(rays.reshape(-1, 6)), nthreads=thread_count())["primitive_ids"]
    ids = ids.numpy().astype(np.int64)
    ids[ids == np.iinfo(np.uint32).max] = -1
    return ids.reshape(res, res)


def camera_azimuth(c2w: np.ndarray) -> float:
    """The camera's azimuth about +y (radians; :func:`ipm.render.cameras.orbit_direction`'s)."""
    back = np.asarray(c2w)[:3, 2]
    return float(np.arctan2(back[0], back[2]))


def crop_box(mask: np.ndarray) -> tuple[float, float, float]:
    """Centre (x, y) and side (pixels) of the square crop around a mask's bounding box."""
    rows, cols = np.nonzero(mask.max(1) > 0.5)[0], np.nonzero(mask.max(0) > 0.5)[0]
    if len(rows) == 0:
        raise ValueError("the mask is empty")
    y0, y1, x0, x1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    return 0.5 * (x0 + x1), 0.5 * (y0 + y1), CROP_MARGIN * max(y1 - y0, x1 - x0, 2)


def _resample(image: np.ndarray, cx: float, cy: float, side: float, res: int) -> np.ndarray:
    """The square ``side`` around (cx, cy) of ``image`` at ``res`` x ``res`` (area-averaged by
    supersampling 4 x 4; outside the image 0)."""
    k = 4
    s = (np.arange(res * k) + 0.5) / (res * k) - 0.5
    xs, ys = cx + s * side - 0.5, cy + s * side - 0.5
    xi = np.clip(np.round(xs).astype(int), -1, image.shape[1])
    yi = np.clip(np.round(ys).astype(int), -1, image.shape[0])
    padded = np.pad(image, 1)
    out = padded[(yi + 1)[:, None], (xi + 1)[None, :]]
    return out.reshape(res, k, res, k).mean((1, 3)).astype(np.float32)


def encode_view(mask: np.ndarray, c2w: np.ndarray | None, fov_x: float | None, class_mask: np.ndarray | None = None,
                n_channels: int = 1, res: int = NET_RES) -> tuple[np.ndarray, np.ndarray]:
    """The network's input for one view: the image (n_channels, res, res), the mask and, for a
    generator with a class mask, that mask (zeros where not given), and the camera numbers (N_COND,;
    ``c2w`` and ``fov_x`` None: the camera hidden, :data:`N_COND`)."""
    h, w = mask.shape
    cx, cy, side = crop_box(mask)
    image = np.zeros((n_channels, res, res), np.float32)
    image[0] = _resample(mask.astype(np.float32), cx, cy, side, res)
    given = class_mask is not None and n_channels > 1
    if given:
        image[1] = _resample(class_mask.astype(np.float32), cx, cy, side, res)
    if c2w is None:
        from ipm.photo import DEFAULT_FOV

        f, elevation, lens = 0.5 * w / np.tan(0.5 * DEFAULT_FOV), 0.0, 0.0
    else:
        f, elevation, lens = 0.5 * w / np.tan(0.5 * fov_x), camera_pitch(c2w), np.tan(0.5 * fov_x)
    cond = np.array([elevation, lens, (cx - 0.5 * w) / f, (cy - 0.5 * h) / f, side / f, float(given)], np.float32)
    return image, cond


def camera_pitch(c2w: np.ndarray) -> float:
    """How far the camera looks below the horizon (radians; ``ipm.photo``'s pitch)."""
    return float(np.arcsin(np.clip(np.asarray(c2w)[1, 2], -1.0, 1.0)))


def targets(gen, sample: Sample, camera_hidden: bool = False) -> dict:
    """What the network learns of a sample, in the search's coordinates: unit parameters, which of
    them shape it, the discrete values' class indices, the yaw relative to the camera's azimuth (as
    a unit vector, and whether it matters), and the offsets from the anchor (in the camera's
    horizontal frame, over the anchor's height) with the log of the object's height over the
    anchor's (the scale then follows from the parameters, as ``Problem.initial_z`` sets it); with
    ``camera_hidden`` the camera's pitch and log tan(fov / 2) after them."""
    from ipm.io.views import Views
    from ipm.pose import yaw_matrix
    from ipm.problem import Problem, estimate_anchor

    spec = gen.spec
    views = Views(fov_x=sample.fov_x, width=sample.mask.shape[1], height=sample.mask.shape[0],
                  c2w=sample.c2w[None], masks=sample.mask[None])
    anchor_t, anchor_s = estimate_anchor(views)
    azimuth = camera_azimuth(sample.c2w)
    offset = yaw_matrix(-azimuth) @ ((sample.translation - anchor_t) / anchor_s)
    rel_yaw = sample.yaw - azimuth
    height = Problem(gen, anchor_t, anchor_s).object_height(spec.to_unit(spec.clip(sample.x)))  # as the search sets it
    levels = np.round(sample.x[spec.discrete] - spec.lower[spec.discrete]).astype(np.int32)
    return {"u": spec.to_unit(spec.clip(sample.x))[~spec.discrete].astype(np.float32),
            "active": gen.active(sample.x)[~spec.discrete].astype(np.float32),
            "levels": levels,
            "yaw": np.array([np.cos(rel_yaw), np.sin(rel_yaw)], np.float32),
            "yaw_on": np.float32(not gen.yaw_symmetric(sample.x)),
            "pose": np.array([offset[0], offset[2], np.log(sample.scale * height / anchor_s)]
                             + ([camera_pitch(sample.c2w), np.log(np.tan(0.5 * sample.fov_x))] if camera_hidden else []),
                             np.float32)}


def make_dataset(gen, n: int, seed: int, progress: bool = False, camera_hidden: bool = False) -> dict:
    """``n`` samples of ``gen`` (:func:`draw_sample` from seeds spawned off ``TRAIN_SEED_BASE + seed``)
    as arrays: ``image`` (n, C, NET_RES, NET_RES) with C = 2 for a generator with a class mask (given
    for three samples in four, so the network also reads views without one), ``cond``, and the
    :func:`targets` stacked; ``camera_hidden``: a photo's views (:data:`PHOTO_ELEVATIONS`, no
    camera numbers, the camera among the targets)."""
    from tqdm import tqdm

    channels = 2 if gen.mask_class is not None else 1
    rows = []
    for i, ss in enumerate(tqdm(np.random.SeedSequence(TRAIN_SEED_BASE + seed).spawn(n), desc=f"samples {gen.name}",
                                disable=not progress, leave=False)):
        rng = np.random.default_rng(ss)
        sample = draw_sample(gen, rng, elevations=PHOTO_ELEVATIONS if camera_hidden else ELEVATIONS)
        given = sample.class_mask if rng.random() < 0.75 else None
        seen = (None, None) if camera_hidden else (sample.c2w, sample.fov_x)
        image, cond = encode_view(sample.mask, *seen, given, channels)
        rows.append({"image": image, "cond": cond, **targets(gen, sample, camera_hidden)})
    return {k: np.stack([r[k] for r in rows]) for k in rows[0]}
