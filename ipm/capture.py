"""Captures in other frames and formats, brought to the scene convention (``docs/design``,
"Scene convention": y up, the object standing on y = 0): z-up or tilted worlds (nerfstudio,
colmap2nerf, instant-ngp) and COLMAP sparse models (through pycolmap). The result is an ordinary
:class:`Views` whose ``world_from_input`` maps the input's world to ours, so a reconstruction can
be taken back."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ipm.errors import UserError
from ipm.io.lens import Lens
from ipm.io.views import Views, _read_mask, load_views, resampled_masks
from ipm.render.cameras import colmap_to_gl

AXES = {"x": (1, 0, 0), "-x": (-1, 0, 0), "y": (0, 1, 0), "-y": (0, -1, 0), "z": (0, 0, 1), "-z": (0, 0, -1)}
UP_CHOICES = (*AXES, "auto")
"""``--up``: a world axis, or ``auto`` (perpendicular to the cameras' right vectors)."""


def up_from_cameras(c2w: np.ndarray) -> np.ndarray:
    """The world's up direction from how people hold cameras: level, so each camera's right
    vector (its image's +x) is horizontal. Up is the direction most nearly perpendicular to all of
    them (the least eigenvector of their scatter), on the side of the cameras' mean up vector.
    Exact for cameras without roll at any elevation; refused where the right vectors are all
    parallel (one view, or views from one direction), which leaves the tilt about them open."""
    c2w = np.asarray(c2w, np.float64)
    right = c2w[:, :3, 0] / np.linalg.norm(c2w[:, :3, 0], axis=1, keepdims=True)
    values, vectors = np.linalg.eigh(right.T @ right / len(right))
    if values[1] < 0.02:
        raise UserError("the views' directions cannot tell the world's up axis (one view, or all from one side); "
                        "give it with --up x|y|z|-x|-y|-z")
    up = vectors[:, 0]
    return up if np.dot(up, c2w[:, :3, 1].sum(0)) >= 0 else -up


def rotation_to_y(up: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) that takes the unit vector ``up`` to +y."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    y = np.array([0.0, 1.0, 0.0])
    axis, c = np.cross(up, y), float(np.dot(up, y))
    if np.linalg.norm(axis) < 1e-9:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # half turn about x
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def ground_height(views: Views, n: int = 64) -> float:
    """Height (y) of the lowest point where the masks of two or more views agree: at or below the
    object's foot (below a base seen only from above by up to its radius times the tangent of the
    lowest camera's elevation, so the diff path lets the foot float: ``Views.ground_known``). One
    view sees no depth, so there the input's origin stays on the ground."""
    if len(views) < 2:
        return 0.0
    from ipm.hull import grid_points, mask_values, object_box

    lo, hi = object_box(views)
    pts = grid_points(lo, hi, n)
    inside = mask_values(views, pts).min(0) > 0.5
    return float(pts[inside, 1].min() - 0.5 * (hi[1] - lo[1]) / n)


def upright(views: Views, up: str = "y") -> Views:
    """``views`` in a world with y up and the object's foot on y = 0. ``up``: the input world's up
    axis (``y``: already in the convention, unchanged) or ``auto`` (:func:`up_from_cameras`)."""
    if up not in UP_CHOICES:
        raise UserError(f"unknown up axis {up!r} (known: {', '.join(UP_CHOICES)})")
    if up == "y":
        return views
    direction = up_from_cameras(views.c2w) if up == "auto" else np.asarray(AXES[up], np.float64)
    turn = np.eye(4)
    turn[:3, :3] = rotation_to_y(direction)
    turned = replace(views, c2w=turn @ views.c2w)
    lift = np.eye(4)
    lift[1, 3] = -ground_height(turned)
    transform = lift @ turn
    return replace(views, c2w=transform @ views.c2w, world_from_input=transform @ views.world_from_input,
                   ground_known=False)


def unposed_camera(views: Views) -> Views:
    """``views`` as read (``ipm.io.load_views``); a photo its file gives no pose (``Views.posed``
    False, no camera yet) with its camera to estimate (``ipm.photo.unknown_camera_views``), at the
    file's field of view or else ``ipm.photo.DEFAULT_FOV``."""
    if views.posed or views.camera is not None:
        return views
    from ipm.photo import DEFAULT_FOV, unknown_camera_views

    fov_known = views.fov_x is not None
    return unknown_camera_views(views if fov_known else replace(views, fov_x=DEFAULT_FOV), fov_known=fov_known)


def _colmap_camera(cams: dict, used: set[int]) -> Lens:
    """The one camera the images of a COLMAP model share, as a :class:`~ipm.io.lens.Lens`
    (any perspective model: its masks are resampled onto the pinhole twin)."""
    if len(used) != 1:
        raise UserError(f"the COLMAP model's images use {len(used)} cameras; all views must share one")
    cam = cams[used.pop()]
    lens = Lens(cam.model.name, tuple(float(v) for v in cam.params), int(cam.width), int(cam.height))
    lens.camera()  # refuses models that are not perspective cameras
    return lens


def _mask_file(masks: Path, name: str) -> Path:
    """A COLMAP image's mask: ``NAME.png`` (COLMAP's own convention) or the name with its
    extension replaced by ``.png``."""
    for candidate in (masks / f"{name}.png", (masks / name).with_suffix(".png")):
        if candidate.is_file():
            return candidate
    raise UserError(f"no mask for COLMAP image {name} in {masks} (looked for {name}.png and "
                    f"{Path(name).with_suffix('.png')})")


def read_colmap(model: str | Path, images: str | Path, masks: str | Path | None, up: str = "auto") -> Views:
    """The registered images of a COLMAP sparse model (``cameras``/``images`` .bin or .txt) as
    views, in name order, with their masks from ``masks`` (None: from each photo, its alpha or
    its colours: ``ipm.segment``), brought upright (``up``; COLMAP's world has no preferred
    axis, so ``auto`` by default)."""
    import pycolmap

    model, images = Path(model), Path(images)
    masks = None if masks is None else Path(masks)
    for what, folder in (("model", model), ("images", images), ("masks", masks)):
        if folder is not None and not folder.is_dir():
            raise UserError(f"COLMAP {what} folder not found: {folder}")
    try:
        rec = pycolmap.Reconstruction(str(model))
    except (ValueError, RuntimeError) as exc:
        raise UserError(f"cannot read the COLMAP model in {model}: {exc}") from None
    posed = sorted((img for img in rec.images.values() if img.has_pose), key=lambda img: img.name)
    if not posed:
        raise UserError(f"the COLMAP model in {model} has no registered image")
    lens = _colmap_camera(rec.cameras, {img.camera_id for img in posed})
    fov_x, width, height = lens.fov_x, lens.width, lens.height
    lens = None if lens.is_pinhole else lens
    frames, c2w, mask_arr = [], [], []
    for img in posed:
        photo = images / img.name
        frames.append({"file_path": str(photo.resolve())})
        if masks is None:
            mask_arr.append(_read_mask(photo, width, height, alpha=True))
        else:
            frames[-1]["mask_path"] = str(_mask_file(masks, img.name).resolve())
            mask_arr.append(_read_mask(Path(frames[-1]["mask_path"]), width, height))
        c2w.append(colmap_to_gl(img.cam_from_world().matrix()))
    views = Views(fov_x, width, height, np.stack(c2w), resampled_masks(np.stack(mask_arr), lens, model),
                  frames, model, lens=lens)
    return upright(views, up)


def open_views(views: str | Path | None = None, up: str | None = None, colmap: str | Path | None = None,
               images: str | Path | None = None, masks: str | Path | None = None, image: str | Path | None = None,
               mask: str | Path | None = None, fov: float | None = None, segment: str | None = None) -> Views:
    """The input of a reconstruction or baseline: a ``transforms.json`` (its world's ``up`` axis,
    ``y`` by default), a COLMAP model with its images and masks folders (``auto`` by default), or
    one photo (``image``, its ``mask`` or alpha channel or its ``segment``-ed colours, the ``fov`` in degrees if known) whose
    camera is estimated (``ipm.photo``; so is a transforms.json's single frame without its pose:
    :func:`unposed_camera`); exactly one of the three."""
    if sum(x is not None for x in (views, colmap, image)) != 1:
        raise UserError("give one of --views transforms.json, --colmap MODEL (with --images, --masks) "
                        "or --image PHOTO (with --mask, else its alpha or colours)")
    if (mask is not None or fov is not None or segment is not None) and image is None:
        raise UserError("--mask, --fov and --segment go with --image (a photo whose camera is unknown)")
    if image is not None:
        from ipm.photo import photo_views

        if up is not None:
            raise UserError("--up does not apply to --image: the camera's pitch and roll are estimated")
        return photo_views(image, mask, fov, segment or "colour")
    if colmap is None:
        if images is not None or masks is not None:
            raise UserError("--images and --masks go with --colmap (a transforms.json names its own files)")
        return upright(unposed_camera(load_views(views)), up or "y")
    if images is None:
        raise UserError("--colmap needs --images (the photos' folder; --masks: one mask per photo, "
                        "else each photo's alpha or colours)")
    return read_colmap(colmap, images, masks, up or "auto")
