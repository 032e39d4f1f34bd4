"""Views in the instant-ngp / nerfstudio ``transforms.json`` format (``docs/design``, "Inputs").

Camera-to-world matrices use the OpenGL convention: the camera looks down its -z,
+y is up in the image, +x right; the principal point is the image centre.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

import numpy as np
from PIL import Image

from ipm.errors import UserError
from ipm.io.atomic import atomic_path, write_json
from ipm.io.lens import NERFSTUDIO_COEFFICIENTS, Lens, nerfstudio_lens

class EstimatedCamera(Protocol):
    """What views carry when their camera is to be estimated (``ipm.photo.UnknownCamera``): the
    render camera's field of view, a start unless ``fov_known``."""

    fov0: float
    fov_known: bool


@dataclass(frozen=True)
class Views:
    """A set of calibrated views of one object, with their silhouettes."""

    fov_x: float | None
    """Horizontal field of view in radians; None only for a photo whose file gives neither its pose
    nor its field of view (``posed`` False)."""
    width: int
    """Image width in pixels."""
    height: int
    """Image height in pixels."""
    c2w: np.ndarray
    """Camera-to-world matrices, shape (n, 4, 4), OpenGL convention."""
    masks: np.ndarray | None = None
    """Object masks, shape (n, height, width), float32 in {0, 1}; None if not loaded."""
    frames: list[dict] = field(default_factory=list)
    """The raw frame records (file paths relative to ``root``)."""
    root: Path = Path(".")
    """Directory that frame paths are relative to."""
    semantic_labels: dict | None = None
    """Optional label-name -> value map for semantic images."""
    semantics: np.ndarray | None = None
    """Semantic label images (``semantic_path``), shape (n, height, width), uint8; None when the
    frames have none (or they were not loaded)."""
    world_from_input: np.ndarray = field(default_factory=lambda: np.eye(4))
    """The map (4, 4) from the input's world to this one (``ipm.capture.upright``: a z-up capture
    turned y-up, its ground moved to y = 0); the identity for files in the convention."""
    ground_known: bool = True
    """Whether the object stands on y = 0 by the input's word (the convention), not by an estimate
    (``ipm.capture.upright``: the masks' lowest common point lies below a base seen from above)."""
    camera: EstimatedCamera | None = None
    """``ipm.photo.UnknownCamera`` when the (single) view's camera is to be estimated; then ``c2w``
    and ``fov_x`` are the render camera's, a start, not a measurement."""
    lens: Lens | None = None
    """The capture's camera (``ipm.io.lens.Lens``) when it is not the centred square-pixel pinhole:
    masks and label images were resampled onto its pinhole twin (``fov_x``); an image read later
    from ``frames`` goes through ``lens.resample`` too. None for a pinhole capture."""
    lighting: str | None = None
    """The light the colour images were taken under, where the file says (``reference``: synth's
    sky and sun of ``ipm.render.textured``); None for a capture's own, unknown light."""
    posed: bool = True
    """Whether the views' poses are known. False for a photo without one: as read, ``c2w`` the
    identity and no ``camera`` (``ipm.capture.open_views`` gives it its unknown camera)."""

    def __len__(self) -> int:
        return len(self.c2w)

    def input_frame(self) -> dict:
        """``{"world_from_input": 4 x 4 list}`` for a params.json when the views were turned into
        the convention (the mesh is written in the turned world), else nothing."""
        same = np.allclose(self.world_from_input, np.eye(4))
        return {} if same else {"world_from_input": np.asarray(self.world_from_input).tolist()}

    def first(self, n: int | None, minimum: int = 1) -> "Views":
        """The first ``n`` views (all if None); ``UserError`` unless ``minimum <= n <= len(self)``."""
        n = len(self) if n is None else n
        if not minimum <= n <= len(self):
            raise UserError(f"--n-input-views: needs {minimum}..{len(self)} views of {self.root}, got {n}")
        return self.subset(range(n))

    def subset(self, idx) -> "Views":
        """The views with indices ``idx`` (a list), in that order."""
        idx = list(idx)
        masks = None if self.masks is None else self.masks[idx]
        semantics = None if self.semantics is None else self.semantics[idx]
        return replace(self, c2w=self.c2w[idx], masks=masks, frames=[self.frames[i] for i in idx], semantics=semantics)


SEGMENTERS = ("colour", "learned")
"""How a photo without mask or alpha is segmented: ``colour`` (the colour model of its border, for
a plain background: ``ipm.segment.mask_from_image``) or ``learned`` (a photograph with a ground,
shadows and a backdrop: ``ipm.segment.mask_from_photo``)."""


def open_image(path: str | os.PathLike, upright: bool = False) -> Image.Image:
    """The image in ``path``, loaded; ``upright``: turned as its Exif orientation says a viewer
    shows it (a phone's portrait photo is stored on its side with that tag), for a photo whose
    camera is unknown. A capture's views are read as stored: their poses are the stored pixels'."""
    from PIL import ImageOps

    with Image.open(path) as img:
        img.load()
        return ImageOps.exif_transpose(img) if upright else img


def _read_mask(path: Path, width: int, height: int, alpha: bool = False, segment: str = "colour",
               upright: bool = False) -> np.ndarray:
    """The object mask in ``path``; with ``alpha``, a photo's: its alpha channel (RGBA, LA; not one
    that hides nothing), else segmented from its colours (a grey photo's as grey colours) by
    ``segment`` (:data:`SEGMENTERS`, ``ipm.segment``); ``upright``: read as :func:`open_image` turns it."""
    if not path.is_file():
        raise UserError(f"mask file not found: {path}")
    try:
        img = open_image(path, upright)
        see_through = img.mode in ("RGBA", "LA", "PA") or "transparency" in img.info
        if alpha:  # a photo: its colours (a grey photo's as grey ones, CMYK's as RGB) and its alpha if any
            img = img.convert("RGBA" if see_through else "RGB")
        elif img.mode in ("1", "P"):  # bits and palettes as the values they stand for
            img = img.convert("L" if img.mode == "1" else "RGBA" if see_through else "RGB")
        img = np.asarray(img)
    except Exception as exc:
        raise UserError(f"cannot read mask {path}: {exc}") from None
    if segment not in SEGMENTERS:
        raise UserError(f"unknown segmenter {segment!r} (known: {', '.join(SEGMENTERS)})")
    if alpha and img.shape[2] == 4 and img[..., 3].min() == 255:  # an alpha channel that hides nothing
        img = img[..., :3]
    if alpha and img.shape[2] == 3:
        from ipm.segment import mask_from_image, mask_from_photo

        try:
            img = ((mask_from_photo if segment == "learned" else mask_from_image)(img) * 255).astype(np.uint8)
        except UserError as exc:
            raise UserError(f"{path}: no mask given, no alpha channel, and {exc}") from None
    elif alpha:
        img = img[..., 3]
    elif img.ndim == 3:
        img = img[..., 0] if img.shape[2] < 4 else img[..., 3] if img[..., :3].max() == 0 else img[..., 0]
    if img.shape != (height, width):
        raise UserError(
            f"mask {path} is {img.shape[1]}x{img.shape[0]} px but transforms.json says {width}x{height}"
        )
    mask = (img > 127).astype(np.float32)
    share = mask.mean()
    if share == 0.0:
        raise UserError(f"mask {path} is empty (no object pixel)")
    if share == 1.0:
        raise UserError(f"mask {path} is all object (no background pixel)")
    return mask


def resampled_masks(masks: np.ndarray, lens, source) -> np.ndarray:
    """``masks`` (n, h, w) as the pinhole twin of ``lens`` sees them (unchanged for None);
    ``UserError`` naming ``source`` if a view's object falls outside the twin's frame."""
    if lens is None:
        return masks
    out = (lens.resample(masks.astype(np.float32)) > 0.5).astype(np.float32)
    empty = [i for i, m in enumerate(out) if not m.any()]
    if empty:
        raise UserError(f"{source}: view {empty[0]}'s object lies outside the undistorted image")
    return out


def _shared(path: Path, data: dict, frames: list, key: str):
    """``key``'s value, per frame or at the top level (a frame's own wins), one for all frames:
    the views share one camera; None where no frame has it."""
    values = {json.dumps(fr.get(key, data.get(key)) if isinstance(fr, dict) else data.get(key)) for fr in frames}
    if len(values) > 1:
        raise UserError(f"{path}: frames differ in {key!r}; all views must share one camera")
    return json.loads(values.pop())


def _frame_image(folder: Path, name) -> Path:
    """A frame's image path, relative to the views file's ``folder`` (or absolute); ``.png`` added
    where the name has no extension and no such file exists (NeRF-synthetic leaves it out)."""
    image = folder / str(name)
    return image.with_suffix(".png") if not image.is_file() and not image.suffix else image


def _image_size(path: Path, frames: list) -> tuple[int, int]:
    """Width and height of the first frame's image (``file_path``, else ``mask_path``), for files
    that leave ``w``/``h`` out (NeRF-synthetic)."""
    first = frames[0] if isinstance(frames[0], dict) else {}
    for key in ("file_path", "mask_path"):
        if key in first:
            image = _frame_image(path.parent, first[key])
            try:
                with Image.open(image) as img:
                    return img.size
            except (OSError, ValueError):
                raise UserError(f"{path}: no w/h given and cannot read the image {image} for its size") from None
    raise UserError(f"{path}: no w/h given and frame 0 names no image to read the size from")


def _intrinsics(path: Path, data: dict, frames: list, fov_required: bool = True):
    """Horizontal field of view (radians), width, height and lens from ``camera_angle_x`` or
    ``fl_x`` (nerfstudio, instant-ngp; top level or per frame); ``w``/``h`` from the image when
    absent; the field of view None when neither is given and it is not ``fov_required``. The lens
    (``ipm.io.lens.Lens``) is None for the centred square-pixel pinhole camera the renderers draw;
    otherwise (distortion, ``cx``/``cy`` off centre, ``fl_y`` other than ``fl_x``) the field of
    view is its pinhole twin's, onto which the masks are resampled."""
    get = lambda key: _shared(path, data, frames, key)  # noqa: E731
    try:
        w, h = get("w"), get("h")
        width, height = (int(w), int(h)) if w is not None and h is not None else _image_size(path, frames)
        angle, fl_x = get("camera_angle_x"), get("fl_x")
        focal = 0.5 * width / np.tan(0.5 * float(angle)) if angle is not None else fl_x
        if focal is None and fov_required:
            raise UserError(f"{path}: no camera_angle_x or fl_x: the field of view is unknown")
        if angle is not None and not (np.isfinite(float(angle)) and 0.0 < float(angle) < np.pi):
            raise UserError(f"{path}: camera_angle_x must be in (0, pi), got {angle}")
        if focal is not None and not (np.isfinite(float(focal)) and float(focal) > 0.0):
            raise UserError(f"{path}: fl_x must be a positive focal length in pixels, got {focal}")
        lens = nerfstudio_lens(get("camera_model"), 1.0 if focal is None else float(focal), get("fl_y"), get("cx"),
                               get("cy"), {k: get(k) for k in NERFSTUDIO_COEFFICIENTS}, width, height)
        if focal is None and lens is not None:
            raise UserError(f"{path}: lens distortion, principal point or fl_y given without the focal length "
                            "(fl_x or camera_angle_x)")
    except (TypeError, ValueError) as exc:
        raise UserError(f"{path}: invalid camera field: {exc}") from None
    if width < 8 or height < 8:
        raise UserError(f"{path}: image size {width}x{height} is too small")
    if focal is None:
        return None, width, height, None
    return float(angle) if angle is not None else 2.0 * float(np.arctan(0.5 * width / float(focal))), width, height, lens


def load_views(path: str | os.PathLike | Views, masks: bool = True, semantics: bool = True) -> Views:
    """Read and validate ``transforms.json`` (and its masks); raise ``UserError`` on bad input.
    Views already read (``ipm.capture.open_views``: a COLMAP model, a turned world) pass through.
    A single frame without ``transform_matrix`` (and perhaps without a field of view) is a photo
    read as it is (``Views.posed`` False; ``ipm.capture.open_views`` gives it its unknown camera).

    With ``semantics``, the frames' ``semantic_path`` label images are read too when the frames
    have them (all frames or none; each of the views' size, values 0..2, or up to the largest value
    of the file's ``semantic_labels``; ``ipm.io.semantic``).
    """
    if isinstance(path, Views):
        return path
    path = Path(path)
    if not path.is_file():
        raise UserError(f"views file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"malformed JSON in {path}: {exc}") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: top level must be an object")
    try:
        frames = list(data["frames"])
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{path}: missing or invalid field {exc}") from None
    if not frames:
        raise UserError(f"{path}: no frames")
    posed = any(isinstance(fr, dict) and "transform_matrix" in fr for fr in frames)
    fov_x, width, height, lens = _intrinsics(path, data, frames, fov_required=posed)
    if not posed and len(frames) > 1:
        raise UserError(f"{path}: no frame has a transform_matrix; an unknown camera needs exactly one view")
    c2w = [] if posed else [np.eye(4)]
    for i, fr in enumerate(frames if posed else []):
        try:
            m = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise UserError(f"{path}: frame {i} has no valid transform_matrix") from None
        if m.shape != (4, 4):
            raise UserError(f"{path}: frame {i} transform_matrix must be 4x4, got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise UserError(f"{path}: frame {i} transform_matrix contains NaN or infinity")
        if abs(np.linalg.det(m[:3, :3])) < 1e-6:
            raise UserError(f"{path}: frame {i} transform_matrix is singular")
        c2w.append(m)
    mask_arr = None
    if masks:
        mask_list = []
        for i, fr in enumerate(frames):
            if "mask_path" in fr:
                mask_list.append(_read_mask(path.parent / fr["mask_path"], width, height))
            elif "file_path" in fr:  # the image's alpha (NeRF-synthetic, nerfstudio) or its colours
                mask_list.append(_read_mask(_frame_image(path.parent, fr["file_path"]), width, height, alpha=True))
            else:
                raise UserError(f"{path}: frame {i} has no mask_path (nor a file_path to take the mask from)")
        mask_arr = resampled_masks(np.stack(mask_list), lens, path)
    sem_arr = None
    labelled = [i for i, fr in enumerate(frames) if isinstance(fr, dict) and "semantic_path" in fr]
    if semantics and labelled:
        from ipm.io.semantic import load_labels

        if len(labelled) != len(frames):
            missing = next(i for i in range(len(frames)) if i not in set(labelled))
            raise UserError(f"{path}: frame {missing} has no semantic_path (all frames or none must have one)")
        names = data.get("semantic_labels")
        try:
            top = max(int(v) for v in names.values()) if isinstance(names, dict) and names else 2
        except (TypeError, ValueError):
            raise UserError(f"{path}: semantic_labels must map label names to integers") from None
        sem_arr = np.stack([load_labels(path.parent / fr["semantic_path"], width, height, top) for fr in frames])
        sem_arr = sem_arr if lens is None else lens.resample(sem_arr, nearest=True)
    lighting = data.get("lighting")
    if lighting is not None and lighting not in LIGHTINGS:
        raise UserError(f"{path}: unknown lighting {lighting!r} (known: {', '.join(LIGHTINGS)})")
    return Views(fov_x, width, height, np.stack(c2w), mask_arr, frames, path.parent,
                 data.get("semantic_labels"), sem_arr, lens=lens, lighting=lighting, posed=posed)


def load_photos(views: Views) -> np.ndarray | None:
    """The views' colour images as linear RGB (n, height, width, 3) float in [0, 1], as the pinhole
    twin sees them where the capture has a lens; None where a frame has no colour image (a mask
    alone)."""
    if not views.frames or any("file_path" not in fr for fr in views.frames):
        return None
    images = []
    for fr in views.frames:
        path = _frame_image(views.root, fr["file_path"])
        try:
            rgb = np.asarray(open_image(path, fr.get("upright", False)).convert("RGB"), np.float64) / 255.0
        except (OSError, ValueError) as exc:
            raise UserError(f"cannot read colour image {path}: {exc}") from None
        if rgb.shape[:2] != (views.height, views.width) and views.lens is None:
            raise UserError(f"colour image {path} is {rgb.shape[1]}x{rgb.shape[0]}, expected "
                            f"{views.width}x{views.height}")
        images.append(linear_from_srgb(rgb))
    images = np.stack(images)
    return images if views.lens is None else views.lens.resample(images)


def save_mask(path: str | os.PathLike, mask: np.ndarray) -> None:
    """Write a boolean/float mask as an 8-bit PNG (255 = object), atomically."""
    img = Image.fromarray(((np.asarray(mask) > 0.5) * 255).astype(np.uint8))
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")


def linear_from_srgb(x: np.ndarray) -> np.ndarray:
    """sRGB values in [0, 1] as linear ones."""
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def srgb_bytes(rgb: np.ndarray) -> np.ndarray:
    """A linear float RGB image in [0, 1] as 8-bit sRGB."""
    x = np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (srgb * 255 + 0.5).astype(np.uint8)


def jpeg_bytes(rgb8: np.ndarray, quality: int) -> bytes:
    """An 8-bit RGB image compressed as a JPEG file at ``quality``."""
    import io

    buf = io.BytesIO()
    Image.fromarray(rgb8).save(buf, format="JPEG", quality=int(quality))
    return buf.getvalue()


def jpeg_decode(data: bytes) -> np.ndarray:
    """The 8-bit RGB image (H, W, 3) a JPEG file's bytes hold."""
    import io

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def jpeg_roundtrip(rgb8: np.ndarray, quality: int) -> np.ndarray:
    """An 8-bit RGB image as it reads back after JPEG compression at ``quality``."""
    return jpeg_decode(jpeg_bytes(rgb8, quality))


def save_texture(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an sRGB image (h, w, 3) uint8 as a PNG, atomically."""
    with atomic_path(path) as tmp:
        Image.fromarray(np.asarray(image, np.uint8)).save(tmp, format="PNG")


def save_rgb(path: str | os.PathLike, rgb: np.ndarray, quality: int | None = None) -> None:
    """Write a linear float RGB image in [0, 1] as an sRGB 8-bit PNG (a JPEG of ``quality``
    where one is given), atomically."""
    img = Image.fromarray(srgb_bytes(rgb))
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG") if quality is None else img.save(tmp, format="JPEG", quality=int(quality))


LIGHTINGS = ("reference",)
"""The lights a transforms.json may name (``lighting``): ``reference``, synth's sky and sun."""


def write_views(path: str | os.PathLike, fov_x: float, width: int, height: int,
                frames: list[dict], semantic_labels: dict | None = None, lens: Lens | None = None,
                lighting: str | None = None) -> None:
    """Write a transforms.json; ``frames`` hold paths and (4, 4) ``transform_matrix`` arrays.
    The camera in both focal forms: ``camera_angle_x`` (instant-ngp, NeRF-synthetic) and
    ``fl_x``/``fl_y``/``cx``/``cy`` (nerfstudio's parser needs ``fl_x``); with ``lens`` (an
    ``OPENCV`` one, centred, ``fov_x`` its pinhole twin's) its distortion as nerfstudio writes it."""
    focal = 0.5 * width / np.tan(0.5 * fov_x)
    data = {"camera_angle_x": float(fov_x), "w": int(width), "h": int(height), "fl_x": float(focal),
            "fl_y": float(focal), "cx": 0.5 * width, "cy": 0.5 * height, "camera_model": "PINHOLE"}
    if lens is not None:
        if lens.model != "OPENCV" or (lens.width, lens.height) != (width, height):
            raise ValueError(f"write_views writes an OPENCV lens of the views' size, not {lens.model} "
                             f"{lens.width}x{lens.height}")
        fx, fy, cx, cy, k1, k2, p1, p2 = map(float, lens.params)
        data.update(fl_x=fx, fl_y=fy, cx=cx, cy=cy, camera_model="OPENCV", k1=k1, k2=k2, p1=p1, p2=p2)
    if semantic_labels:
        data["semantic_labels"] = semantic_labels
    if lighting is not None:
        data["lighting"] = lighting
    data["frames"] = [
        {**fr, "transform_matrix": np.asarray(fr["transform_matrix"]).tolist()} for fr in frames
    ]
    write_json(path, data)


def resize_masks(masks: np.ndarray, width: int) -> np.ndarray:
    """Area-averaged masks ``width`` pixels wide (aspect kept), float32 in [0, 1]."""
    n, h, w = masks.shape
    height = max(1, int(round(h * width / w)))
    if (height, width) == (h, w):
        return masks.astype(np.float32)
    if h % height == 0 and w % width == 0:
        return masks.reshape(n, height, h // height, width, w // width).mean((2, 4)).astype(np.float32)
    return np.stack([np.asarray(Image.fromarray(m.astype(np.float32), mode="F").resize(
        (width, height), Image.BOX), np.float32) for m in masks])
