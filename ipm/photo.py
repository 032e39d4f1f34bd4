"""A photo without a camera: its pitch, roll and focal length (the camera genes, which follow the
pose in ``z``) are estimated with the object.

The paper optimises the camera parameters C with the generator's parameters P. From one view
only the camera's attitude relative to the ground and its focal length matter: the object's
position and size along the ray trade against each other anyway (``ipm.problem``). So the
camera stands at (0, 1, 0), one unit above the ground y = 0, looking along -z, pitched down by
``pitch`` and rolled by ``roll``; its horizontal field of view is ``fov``.

The renderer keeps one fixed *render camera* (pitch ``pitch0``, no roll, FOV ``fov0``). A world
point ``p`` seen by the camera ``(pitch, roll, fov)`` lands on the pixel where the render
camera sees ``E + R0 K R(pitch, roll)^T (p - E)``, ``E`` the camera centre and ``K`` the
focal ratio on the image axes: a rotation about the centre and a scaling of the camera's x
and y keep every ray's pixel, so silhouettes are exact and the camera's gradient flows through
the vertices like the object's.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import jax.numpy as jnp
import numpy as np
from PIL import Image

from ipm.errors import UserError
from ipm.io.views import Views, _read_mask, open_image
from ipm.render.cameras import is_fov_deg, pixel_ray

EYE = np.array([0.0, 1.0, 0.0])
"""The camera centre: one unit above the ground (the scale is the object's to choose)."""
PITCH_RANGE = (np.radians(-20.0), np.radians(85.0))
ROLL_LIMIT = np.radians(20.0)
FOV_RANGE = (np.radians(15.0), np.radians(100.0))
PITCH_PRIOR = (0.0, np.radians(60.0))
"""Pitches the initial population is spread over: an object on the ground photographed from
level to steeply above (the authors' and our cases' input views lie within it)."""
DEFAULT_FOV = np.radians(50.0)
"""The starting horizontal field of view when none is given: between a phone's main camera in
portrait (about 50 degrees) and landscape (about 69)."""
FOV_GRID = (25.0, 31.2, 38.7, 47.7, 58.2, 70.0)
"""Horizontal fields of view (degrees) tried by ``ipm reconstruct --fov-grid`` without values
(``CameraSettings.fov_grid`` in ``ipm.search.moves.camera``): six points geometric in tan(fov / 2)
from a short telephoto's to a wide phone camera's."""


def attitude(pitch, roll, xp=np):
    """Camera-to-world rotation (3, 3) of a camera looking along -z, pitched down by ``pitch``
    (radians), then rolled by ``roll`` about its optical axis (``xp``: numpy or jax.numpy)."""
    cp, sp, cr, sr = xp.cos(pitch), xp.sin(pitch), xp.cos(roll), xp.sin(roll)
    down = xp.array([[1.0, 0.0, 0.0], [0.0, cp, sp], [0.0, -sp, cp]])
    spin = xp.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return down @ spin


def c2w(pitch: float, roll: float = 0.0) -> np.ndarray:
    """OpenGL camera-to-world matrix (4, 4) of the camera at :data:`EYE`."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = attitude(pitch, roll), EYE
    return m


def focal_ratio_bounds(fov0: float) -> tuple[float, float]:
    """Bounds of ``log_focal`` = log(f / f0) for fields of view within :data:`FOV_RANGE`."""
    ratio = lambda fov: np.log(np.tan(0.5 * fov0) / np.tan(0.5 * fov))  # noqa: E731
    return float(ratio(FOV_RANGE[1])), float(ratio(FOV_RANGE[0]))


def fov_of(log_focal: float, fov0: float) -> float:
    """The horizontal field of view of focal ratio ``exp(log_focal)`` relative to ``fov0``."""
    return float(2.0 * np.arctan(np.tan(0.5 * fov0) / np.exp(log_focal)))


@dataclass(frozen=True)
class UnknownCamera:
    """The camera of a single view known only by its image: what the reconstruction estimates."""

    pitch0: float
    """Pitch of the render camera (radians)."""
    fov0: float
    """Horizontal field of view of the render camera (radians): the given one, or a start."""
    fov_known: bool
    """Whether the field of view was given (then ``log_focal`` stays 0)."""
    foot: tuple[float, float, int, int] = (0.0, 0.0, 1, 1)
    """The mask's foot pixel (x, y: the lowest row's middle) and the image's width and height."""
    fov_chosen: bool = False
    """Whether the held field of view was chosen by the fit from a grid (``CameraSettings.fov_grid``
    in ``ipm.search.moves.camera``) rather than given."""
    proposed: bool = False
    """Whether the render camera's pitch, and its field of view unless given (then held), were
    proposed by the camera-hidden regressor (``ipm.learned.propose.propose_camera``)."""

    @classmethod
    def of(cls, numbers) -> "UnknownCamera":
        """The camera of ``numbers`` (pitch0, fov0, the foot's x and y, width, height; traced
        values inside a compiled program, ``ipm.problem.Problem.constants``): what
        :meth:`placement` and :meth:`to_render` read."""
        return cls(numbers[0], numbers[1], True, (numbers[2], numbers[3], numbers[4], numbers[5]))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the camera genes."""
        lo_f, hi_f = focal_ratio_bounds(self.fov0) if not self.fov_known else (0.0, 0.0)
        return np.array([PITCH_RANGE[0], -ROLL_LIMIT, lo_f]), np.array([PITCH_RANGE[1], ROLL_LIMIT, hi_f])

    def spread(self, n: int, rng: np.random.Generator) -> list[np.ndarray]:
        """Camera genes of ``n`` starts: level, at the starting field of view, pitches stratified
        over :data:`PITCH_PRIOR`. (Spreading the field of view over 25-75 degrees too was no
        better on the dev cups: cup_1 pitch error +4.4 -> +6.1 degrees, field of view +43 -> +68 %;
        cup_2 -5.8 -> -6.6 degrees, +17 -> -1 %; seed 0.)"""
        lo, hi = PITCH_PRIOR
        pitch = lo + (rng.permutation(n) + rng.random(n)) / n * (hi - lo)
        return [np.array([p, 0.0, 0.0]) for p in pitch]

    def placement(self, genes, xp=np):
        """Where the camera ``genes`` puts the object: the point where the ray through the mask's
        foot meets the ground, and the factor (distance to that point over the render camera's,
        over the focal ratio) that keeps the object's image size. The object's translation offsets
        and scale ride on these (``ipm.problem``), so a pitch or focal step keeps the foot on its
        pixel and the object its size in the image: the camera's genes then change how the object
        is seen, not where, and Adam can move them without dragging the pose along."""
        x, y, width, height = self.foot
        f0 = 0.5 * width / xp.tan(0.5 * self.fov0)

        def contact(pitch, roll, log_focal):
            f = f0 * xp.exp(log_focal)
            d = attitude(pitch, roll, xp) @ xp.stack([(x - 0.5 * width) / f, -(y - 0.5 * height) / f,
                                                      -xp.ones_like(f)])
            down = xp.minimum(d[1], -1e-2)  # a ray at or above the horizon: far, not infinite
            return EYE + d * (-EYE[1] / down), f

        here, f = contact(genes[0], genes[1], genes[2])
        base, f_base = contact(self.pitch0, 0.0, 0.0 * genes[2])
        ratio = xp.linalg.norm(here - EYE) / xp.linalg.norm(base - EYE) * f_base / f
        return here, base, ratio

    def to_render(self, points, genes):
        """World points (k, 3) seen by the camera ``genes`` mapped to where the render camera sees
        them at the same pixels (pure JAX)."""
        eye = jnp.asarray(EYE, points.dtype)
        r0 = attitude(self.pitch0, 0.0, jnp).astype(points.dtype)
        r = attitude(genes[0], genes[1], jnp)
        k = jnp.exp(genes[2])
        scale = jnp.stack([k, k, jnp.ones_like(k)])
        return eye + ((points - eye) @ r) * scale @ r0.T

    def describe(self, genes: np.ndarray) -> dict:
        """The estimated camera for params.json (degrees, and its transform_matrix)."""
        pitch, roll, log_focal = (float(g) for g in genes)
        return {"pitch_deg": float(np.degrees(pitch)), "roll_deg": float(np.degrees(roll)),
                "fov_x_deg": float(np.degrees(fov_of(log_focal, self.fov0))),
                "fov_given": self.fov_known and not self.fov_chosen and not self.proposed,
                "fov_from_grid": self.fov_chosen, "proposed": self.proposed,
                "transform_matrix": c2w(pitch, roll).tolist()}


def heading(c2w_gl: np.ndarray) -> float:
    """The direction (radians about +y) a camera looks in, 0 along -z."""
    forward = -np.asarray(c2w_gl)[:3, 2]
    return float(np.arctan2(-forward[0], -forward[2]))


def registration(camera: dict, c2w_given: np.ndarray) -> np.ndarray:
    """The similarity (4, 4) from a photo's world to a given camera's world that keeps both
    grounds and the vertical: the estimated ``camera`` (``UnknownCamera.describe``) goes to the
    given camera's position and heading, scaled by the given camera's height over the ground
    (ours stands one unit above it). How a camera-withheld result is scored in the given world: a
    pitch error moves the object along the ground and changes its size, it does not tip it over."""
    c2w_given, est = np.asarray(c2w_given, np.float64), np.asarray(camera["transform_matrix"], np.float64)
    scale = float(c2w_given[1, 3]) / EYE[1]
    if scale <= 0:
        raise UserError("the given camera is not above the ground y = 0")
    from ipm.metrics.align import yaw_matrix

    m = np.eye(4)
    m[:3, :3] = scale * yaw_matrix(heading(c2w_given) - heading(est))
    m[:3, 3] = c2w_given[:3, 3] - m[:3, :3] @ est[:3, 3]
    return m


def placed_pose(pose: dict, place: np.ndarray) -> dict:
    """``pose`` (``Problem.decode``) moved by ``place`` (:func:`registration`: a turn about the
    vertical, a scale and a shift)."""
    scale = float(np.cbrt(np.linalg.det(place[:3, :3])))
    rot = place[:3, :3] / scale
    return {**pose, "yaw": float(pose["yaw"] + np.arctan2(rot[0, 2], rot[0, 0])),
            "translation": (place[:3, :3] @ np.asarray(pose["translation"]) + place[:3, 3]).tolist(),
            "scale": float(pose["scale"] * scale)}


def misplaced(vertices: np.ndarray, c2w_given: np.ndarray, fov_x: float, width: int, height: int,
              foot: tuple[float, float], d_pitch: float = 0.0, fov_rel: float = 0.0) -> np.ndarray:
    """Where :func:`registration` would put ``vertices`` (the given world's exact shape) had the
    camera-withheld fit got the shape exactly and only the camera wrong: pitched down ``d_pitch``
    radians more, its horizontal field of view ``fov_rel`` too wide. The ray through the ``foot``
    pixel then meets the ground elsewhere and the object keeps its size in the image, so the
    world IoU of the result is what the camera's error alone costs (``bench/camera_sensitivity.py``)."""

    def ground(cam, fov):
        eye, ray = pixel_ray(*foot, cam, fov, width, height)
        if ray[1] >= 0:
            raise UserError("the foot pixel's ray does not meet the ground")
        return eye + ray * (-eye[1] / ray[1]), 0.5 * width / np.tan(0.5 * fov)

    given = np.asarray(c2w_given, np.float64)
    wrong = given.copy()
    wrong[:3, :3] = given[:3, :3] @ attitude(d_pitch, 0.0)  # pitched down d_pitch more about its own x axis
    (here, f), (there, f_wrong) = ground(given, fov_x), ground(wrong, fov_x * (1.0 + fov_rel))
    eye = given[:3, 3]
    scale = np.linalg.norm(there - eye) / np.linalg.norm(here - eye) * f / f_wrong
    return there + scale * (np.asarray(vertices, np.float64) - here)


def camera_errors(camera: dict, c2w_given: np.ndarray, fov_given: float) -> dict:
    """Pitch and roll errors (degrees) and the relative field-of-view error of an estimated
    ``camera`` against a given one."""
    r = np.asarray(c2w_given)[:3, :3]
    pitch = np.degrees(np.arcsin(np.clip(r[1, 2], -1, 1)))  # the optical axis -z_cam below the horizon
    roll = np.degrees(np.arctan2(r[1, 0], r[1, 1]))  # the image's x axis out of the horizontal
    return {"pitch_deg": camera["pitch_deg"] - float(pitch), "roll_deg": camera["roll_deg"] - float(roll),
            "fov_rel": camera["fov_x_deg"] / float(np.degrees(fov_given)) - 1.0}


def exif_fov(focal_35mm: float, width: int, height: int) -> float:
    """Horizontal field of view (radians) of a photo from its 35 mm equivalent focal length
    (Exif FocalLengthIn35mmFilm): the equivalence holds on the diagonal, 43.27 mm of a 36 x 24 mm
    frame, whatever the photo's aspect."""
    across = 0.5 * np.hypot(36.0, 24.0) * width / np.hypot(width, height)
    return float(2.0 * np.arctan(across / focal_35mm))


def photo_views(image: str, mask: str | None = None, fov_deg: float | None = None, segment: str = "colour") -> Views:
    """One photo as views with an unknown camera: the mask from ``mask`` (255 = object), else the
    photo's alpha, else segmented by ``segment`` (``ipm.io.views.SEGMENTERS``); the horizontal field of view ``fov_deg`` when known, else from the
    photo's Exif 35 mm equivalent focal length when it has one, else estimated."""
    from pathlib import Path

    path = Path(image)
    if not path.is_file():
        raise UserError(f"image not found: {path}")
    try:
        with Image.open(path) as img:
            focal_35mm = img.getexif().get_ifd(0x8769).get(0xA405)  # Exif FocalLengthIn35mmFilm
        width, height = open_image(path, upright=True).size  # as a viewer shows it
    except (OSError, ValueError) as exc:
        raise UserError(f"cannot read image {path}: {exc}") from None
    if fov_deg is not None and not is_fov_deg(fov_deg):
        raise UserError(f"--fov: needs 1 to 170 degrees (horizontal), got {fov_deg}")
    if fov_deg is None and focal_35mm:
        fov_deg = float(np.degrees(exif_fov(float(focal_35mm), width, height)))
    m = _read_mask(Path(mask), width, height, upright=True) if mask is not None else \
        _read_mask(path, width, height, alpha=True, segment=segment, upright=True)
    return unknown_camera_views(Views(np.radians(fov_deg) if fov_deg else DEFAULT_FOV, width, height, np.eye(4)[None],
                                      m[None], [{"file_path": str(path.resolve()), "upright": True}], path.parent),
                                fov_known=fov_deg is not None)


def unknown_camera_views(views: Views, fov_known: bool, pitch0: float | None = None) -> Views:
    """``views`` (one) marked as having an unknown camera (and no pose); the render camera at
    ``pitch0`` (radians), by default the prior's middle."""
    if len(views) != 1:
        raise UserError(f"an unknown camera needs exactly one view, got {len(views)}")
    from ipm.problem import foot_pixel  # the anchor's foot, so both place the object alike

    foot = (*foot_pixel(views.masks[0]), views.width, views.height)
    pitch0 = float(np.mean(PITCH_PRIOR)) if pitch0 is None else float(pitch0)
    camera = UnknownCamera(pitch0, float(views.fov_x), fov_known, foot)
    return replace(views, c2w=c2w(camera.pitch0)[None], camera=camera, posed=False)


def withheld(given: Views, fov_given: bool = False) -> Views:
    """The first of ``given`` (posed views) as a photo: its camera withheld, and its field of view
    too unless ``fov_given`` (then :data:`DEFAULT_FOV` is the start)."""
    return unknown_camera_views(given if fov_given else replace(given, fov_x=DEFAULT_FOV), fov_known=fov_given)


def at_proposed_camera(photo: Views, pitch: float, fov: float) -> Views:
    """A photo's views (camera unknown) with the render camera moved to a proposed ``pitch`` and,
    where the photo's field of view is not known, held at the proposed ``fov`` (radians;
    ``ipm.learned.propose.propose_camera``)."""
    views = unknown_camera_views(photo if photo.camera.fov_known else replace(photo, fov_x=float(fov)), True,
                                 pitch0=pitch)
    return replace(views, camera=replace(views.camera, proposed=True))


def scored_placement(problem, z: np.ndarray, given: Views) -> tuple[np.ndarray, dict]:
    """A camera-withheld result ``z`` placed in the world of the view it was withheld from: the
    similarity (:func:`registration`) and what params.json records of it (the placed pose, the
    photo's own, the camera's errors)."""
    estimate = problem.decode(z)
    place = registration(estimate["camera"], given.c2w[0])
    return place, {"pose": placed_pose(estimate["pose"], place), "photo_pose": estimate["pose"],
                   "camera_error": camera_errors(estimate["camera"], given.c2w[0], given.fov_x)}
