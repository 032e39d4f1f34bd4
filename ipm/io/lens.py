"""Real cameras: lens distortion, an off-centre principal point, non-square pixels.

The renderers draw a centred, square-pixel pinhole camera. A capture's camera (COLMAP, nerfstudio,
instant-ngp) rarely is one, so its masks and label images are resampled onto the pinhole camera
of the same size and horizontal focal length that sees the same rays (what COLMAP's
``image_undistorter`` does); pycolmap's camera models map those rays to the capture's pixels.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ipm.errors import UserError

CENTRE_TOLERANCE_PX = 0.01
"""A principal point this close to the image centre, and focal lengths this close (relative),
count as the pinhole camera already: nothing is resampled."""


@dataclass(frozen=True)
class Lens:
    """A capture's camera as a COLMAP camera model: ``model`` (``OPENCV``, ``SIMPLE_RADIAL``, ...)
    and its ``params`` in COLMAP's order (``fx, fy, cx, cy, k1, ...``; pixel centres at +0.5)."""

    model: str
    params: tuple[float, ...]
    width: int
    height: int

    def camera(self):
        import pycolmap

        try:
            cam = pycolmap.Camera(model=self.model, width=self.width, height=self.height, params=list(self.params))
        except Exception:  # pycolmap raises plain exceptions for unknown models
            raise UserError(f"unknown camera model {self.model!r}") from None
        if not cam.verify_params():
            raise UserError(f"camera model {self.model} takes the parameters ({cam.params_info}), "
                            f"got {len(self.params)}")
        if cam.is_spherical() or not cam.focal_length_idxs():
            raise UserError(f"camera model {self.model} is not a perspective camera")
        return cam

    @property
    def focal(self) -> float:
        """The pinhole twin's focal length in pixels: the capture's horizontal one."""
        return float(self.camera().focal_length_x)

    @property
    def fov_x(self) -> float:
        """The pinhole twin's horizontal field of view (radians)."""
        return 2.0 * float(np.arctan(0.5 * self.width / self.focal))

    @property
    def is_pinhole(self) -> bool:
        """Whether the capture's camera is the centred square-pixel pinhole already."""
        cam = self.camera()
        return _centred_square(cam.focal_length_x, cam.focal_length_y, cam.principal_point_x, cam.principal_point_y,
                               [self.params[i] for i in cam.extra_params_idxs()], self.width, self.height)

    def source_pixels(self) -> np.ndarray:
        """(height, width, 2) where each pixel centre of the pinhole twin lies in the capture's
        image, in array coordinates (column, row; the first pixel's centre at 0, 0). Read-only,
        and kept for the last lens: masks, labels and each photo of a capture share one map."""
        return _source_pixels(self)

    def resample(self, images: np.ndarray, nearest: bool = False) -> np.ndarray:
        """``images`` (n, height, width[, channels]) seen by the capture's camera, as its pinhole
        twin sees them: bilinear (``nearest`` for labels), zero where the twin sees past the
        capture's frame. The dtype is kept (floats stay floats; integers are rounded)."""
        images = np.asarray(images)
        if images.shape[1:3] != (self.height, self.width):
            raise UserError(f"images are {images.shape[2]}x{images.shape[1]} px, the camera {self.width}x{self.height}")
        src = self.source_pixels()
        return sample_image(images, src[..., 0], src[..., 1], nearest)

    def twin_margin(self) -> int:
        """Pixels the pinhole twin's canvas must grow by on every side to hold all that the capture
        sees (a barrel lens sees past the twin's frame): for :meth:`from_twin`."""
        x, y = self._twin_pixels_of_capture(0)
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise UserError(f"the {self.model} lens {self.params} cannot be undone over its whole frame "
                            "(its distortion turns back before the corners)")
        over = max(-x.min(), -y.min(), x.max() - (self.width - 1), y.max() - (self.height - 1), 0.0)
        return int(np.ceil(over)) + 2

    def from_twin(self, images: np.ndarray, margin: int, nearest: bool = False) -> np.ndarray:
        """The inverse of :meth:`resample`: ``images`` (n, height + 2 margin, width + 2 margin[,
        channels]) drawn by the pinhole twin on a canvas ``margin`` pixels wider on every side (the
        same focal length), as the capture's camera sees them. For synthesising distorted captures."""
        images = np.asarray(images)
        if images.shape[1:3] != (self.height + 2 * margin, self.width + 2 * margin):
            raise UserError(f"twin images are {images.shape[2]}x{images.shape[1]} px, the camera with its margin "
                            f"{self.width + 2 * margin}x{self.height + 2 * margin}")
        x, y = self._twin_pixels_of_capture(margin)
        return sample_image(images, x, y, nearest)

    def _twin_pixels_of_capture(self, margin: int) -> tuple[np.ndarray, np.ndarray]:
        """Where each capture pixel's ray meets the twin's canvas (``margin`` px wider on every
        side), in its array coordinates (column, row)."""
        cols, rows = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        rays = np.asarray(self.camera().cam_from_img(np.stack([cols.ravel(), rows.ravel()], -1)), np.float64)
        f = self.focal
        x = f * rays[:, 0] + 0.5 * self.width + margin - 0.5
        y = f * rays[:, 1] + 0.5 * self.height + margin - 0.5
        return x.reshape(self.height, self.width), y.reshape(self.height, self.width)


def sample_image(images: np.ndarray, x: np.ndarray, y: np.ndarray, nearest: bool) -> np.ndarray:
    """``images`` (n, h, w[, channels]) read at the array coordinates ``x`` (columns), ``y`` (rows)
    of an output grid: bilinear (``nearest`` for labels), zero outside; the dtype kept (floats stay
    floats; integers are rounded)."""
    height, width = images.shape[1:3]
    if nearest:
        c, r = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
        inside = (c >= 0) & (c < width) & (r >= 0) & (r < height)
        out = images[:, np.clip(r, 0, height - 1), np.clip(c, 0, width - 1)]
        return np.where(_expand(inside, out), out, 0).astype(images.dtype)
    c0, r0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - c0, y - r0
    total = 0.0
    for dc, dr, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        c, r = c0 + dc, r0 + dr
        inside = (c >= 0) & (c < width) & (r >= 0) & (r < height)
        tap = images[:, np.clip(r, 0, height - 1), np.clip(c, 0, width - 1)].astype(np.float64)
        total = total + _expand(np.where(inside, w, 0.0), tap) * tap
    if np.issubdtype(images.dtype, np.integer):
        info = np.iinfo(images.dtype)
        return np.clip(np.rint(total), info.min, info.max).astype(images.dtype)
    return total.astype(images.dtype)


@lru_cache(maxsize=1)
def _source_pixels(lens: Lens) -> np.ndarray:
    """:meth:`Lens.source_pixels`, once per lens (a 12-megapixel map takes seconds)."""
    cam, f = lens.camera(), lens.focal
    cols, rows = np.meshgrid(np.arange(lens.width) + 0.5, np.arange(lens.height) + 0.5)
    rays = np.stack([(cols - 0.5 * lens.width) / f, (rows - 0.5 * lens.height) / f, np.ones_like(cols)], -1)
    px = np.asarray(cam.img_from_cam(rays.reshape(-1, 3), check_cheirality=False), np.float64)
    out = px.reshape(lens.height, lens.width, 2) - 0.5
    out.setflags(write=False)
    return out


def _centred_square(fx: float, fy: float, cx: float, cy: float, extras, width: int, height: int) -> bool:
    """Whether a camera is the centred square-pixel pinhole the renderers draw: no distortion
    term, fy = fx, the principal point within :data:`CENTRE_TOLERANCE_PX` of the centre."""
    return (not any(float(e) != 0.0 for e in extras) and abs(fy / fx - 1.0) < 1e-6
            and abs(cx - 0.5 * width) < CENTRE_TOLERANCE_PX and abs(cy - 0.5 * height) < CENTRE_TOLERANCE_PX)


def _expand(per_pixel: np.ndarray, like: np.ndarray) -> np.ndarray:
    """(height, width) broadcast against (n, height, width[, channels])."""
    return per_pixel.reshape((1,) + per_pixel.shape + (1,) * (like.ndim - 3))


NERFSTUDIO_COEFFICIENTS = ("k1", "k2", "k3", "k4", "p1", "p2")
"""The lens distortion fields of nerfstudio and instant-ngp files."""


def nerfstudio_lens(model: str | None, fx: float, fy: float | None, cx: float | None, cy: float | None,
                    coefficients: dict, width: int, height: int) -> Lens | None:
    """The COLMAP model of a nerfstudio / instant-ngp camera: ``PINHOLE`` / ``SIMPLE_PINHOLE`` /
    ``OPENCV`` (k1, k2, p1, p2; k3 too: COLMAP's ``FULL_OPENCV``) or ``OPENCV_FISHEYE`` (k1-k4);
    None for the centred square-pixel pinhole (decided here, so that such files never load
    pycolmap). nerfstudio's ``OPENCV`` k4 (an r^8 term no COLMAP model has) and other models are
    refused."""
    k = {name: float(coefficients.get(name) or 0.0) for name in NERFSTUDIO_COEFFICIENTS}
    fy = float(fx) if fy is None else float(fy)
    cx = 0.5 * width if cx is None else float(cx)
    cy = 0.5 * height if cy is None else float(cy)
    base = (float(fx), fy, cx, cy)
    model = model or "OPENCV"
    if model not in ("OPENCV", "OPENCV_FISHEYE", "PINHOLE", "SIMPLE_PINHOLE"):
        raise UserError(f"camera_model {model!r} is not supported (known: OPENCV, OPENCV_FISHEYE, PINHOLE, "
                        "SIMPLE_PINHOLE)")
    if _centred_square(float(fx), fy, cx, cy, k.values(), width, height):
        return None
    if model == "OPENCV_FISHEYE":
        if k["p1"] or k["p2"]:
            raise UserError("OPENCV_FISHEYE has no tangential terms, but p1/p2 are given")
        return Lens("OPENCV_FISHEYE", base + (k["k1"], k["k2"], k["k3"], k["k4"]), width, height)
    if k["k4"]:
        raise UserError(f"{model}: k4 (an r^8 radial term) is not supported; undistort the images first")
    if k["k3"]:
        return Lens("FULL_OPENCV", base + (k["k1"], k["k2"], k["p1"], k["p2"], k["k3"], 0.0, 0.0, 0.0), width, height)
    return Lens("OPENCV", base + (k["k1"], k["k2"], k["p1"], k["p2"]), width, height)
