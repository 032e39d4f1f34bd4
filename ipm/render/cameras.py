"""Camera helpers: OpenGL camera-to-world matrices (transforms.json) and their Mitsuba sensors."""
from __future__ import annotations

import numpy as np

# Mitsuba's camera looks down +z with +x to the left of the image; OpenGL's looks down -z
# with +x to the right. Flipping both axes maps one frame onto the other.
_GL_TO_MI = np.diag([-1.0, 1.0, -1.0, 1.0])


FOV_LIMITS_DEG = (1.0, 170.0)
"""The horizontal fields of view (degrees) a camera given to us may have: a case's lens, ``--fov``,
a ``fov_grid`` value."""


def is_fov_deg(value) -> bool:
    """Whether ``value`` is a number (not a bool) of degrees within :data:`FOV_LIMITS_DEG` (NaN is not)."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and FOV_LIMITS_DEG[0] <= value <= FOV_LIMITS_DEG[1])


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """OpenGL camera-to-world matrix of a camera at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    if abs(np.dot(back, up / np.linalg.norm(up))) > 0.999:
        up = np.array([0.0, 0.0, 1.0])
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    true_up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, true_up, back, eye
    return m


def orbit_direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector from an orbit's centre to its camera (azimuth about +y from +z, elevation above
    the centre's horizontal plane)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])


def orbit_camera(center, distance: float, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """A camera on a sphere around ``center`` (:func:`orbit_direction`)."""
    return look_at(np.asarray(center) + distance * orbit_direction(azimuth_deg, elevation_deg), center)


def mitsuba_to_world(c2w_gl: np.ndarray) -> np.ndarray:
    """Mitsuba sensor ``to_world`` matrix for an OpenGL camera-to-world matrix."""
    return np.asarray(c2w_gl, np.float64) @ _GL_TO_MI


CLIP = (1e-3, 1e4)
"""A sensor's near and far clipping distances for a camera 0.1 to 100 units from the origin, where
the scene's object stands; :func:`clip_planes` scales them beyond."""


def clip_planes(c2w_gl: np.ndarray) -> tuple[float, float]:
    """Near and far clipping distances of the camera ``c2w_gl``: :data:`CLIP`, scaled with the
    camera's distance from the origin where it is under 0.1 or over 100 units (a mesh file in
    millimetres, framed by its size, stood beyond a fixed far plane and rendered empty)."""
    d = float(np.linalg.norm(np.asarray(c2w_gl, np.float64)[:3, 3]))
    return CLIP[0] * min(1.0, max(d, 1e-6) / 0.1), CLIP[1] * max(1.0, d / 100.0)


def sensor_dict(c2w_gl: np.ndarray, fov_x: float, width: int, height: int) -> dict:
    """A Mitsuba perspective sensor (box filter, border sampling for moving silhouettes)."""
    import mitsuba as mi

    near, far = clip_planes(c2w_gl)
    return {
        "type": "perspective",
        "fov": float(np.degrees(fov_x)),
        "fov_axis": "x",
        "near_clip": near,
        "far_clip": far,
        "to_world": mi.ScalarTransform4f(mitsuba_to_world(c2w_gl).tolist()),
        "film": {"type": "hdrfilm", "width": int(width), "height": int(height),
                 "rfilter": {"type": "box"}, "pixel_format": "rgb", "sample_border": True},
    }


def project(points: np.ndarray, c2w_gl: np.ndarray, fov_x: float, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (x right, y down, pixel centres at +0.5) of world points, shape (N, 2)."""
    w2c = np.linalg.inv(c2w_gl)
    p = points @ w2c[:3, :3].T + w2c[:3, 3]
    f = 0.5 * width / np.tan(0.5 * fov_x)
    x = width / 2 + f * p[:, 0] / -p[:, 2]
    y = height / 2 - f * p[:, 1] / -p[:, 2]
    return np.stack([x, y], 1)


def pixel_ray(px: float, py: float, c2w_gl: np.ndarray, fov_x: float, width: int, height: int):
    """Origin and unit direction (world) of the ray through pixel position (px, py)."""
    f = 0.5 * width / np.tan(0.5 * fov_x)
    d_cam = np.array([(px - width / 2) / f, -(py - height / 2) / f, -1.0])
    d = c2w_gl[:3, :3] @ d_cam
    return c2w_gl[:3, 3].copy(), d / np.linalg.norm(d)


# COLMAP's camera frame: +x right, +y down, +z forward (the OpenGL camera with y and z flipped)
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])


def gl_to_colmap(c2w_gl: np.ndarray) -> np.ndarray:
    """COLMAP ``cam_from_world`` (3, 4) of an OpenGL camera-to-world matrix (4, 4).

    The rotation is re-orthonormalised (SVD), so a matrix with rounding noise or a uniform
    scale still gives a valid rigid pose.
    """
    c2w_gl = np.asarray(c2w_gl, np.float64)
    u, _, vt = np.linalg.svd(c2w_gl[:3, :3])
    r_c2w = (u @ vt) @ _FLIP_YZ  # columns: camera x, y (down), z (forward) in world
    eye = c2w_gl[:3, 3]
    r = r_c2w.T
    return np.concatenate([r, (-r @ eye)[:, None]], 1)


def colmap_to_gl(cam_from_world: np.ndarray) -> np.ndarray:
    """OpenGL camera-to-world matrix (4, 4) of a COLMAP ``cam_from_world`` pose (3, 4)."""
    m = np.asarray(cam_from_world, np.float64)
    r, t = m[:3, :3], m[:3, 3]
    out = np.eye(4)
    out[:3, :3] = r.T @ _FLIP_YZ
    out[:3, 3] = -r.T @ t
    return out
