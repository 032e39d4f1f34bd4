"""Real cameras (``ipm.io.lens``): a capture with lens distortion, an off-centre principal point
or non-square pixels is resampled onto the centred pinhole camera the renderers draw, so that a
direction lands where that pinhole camera puts it."""
from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from ipm.errors import UserError
from ipm.io import load_views
from ipm.io.lens import Lens, nerfstudio_lens

W, H = 120, 90
CAMERA = dict(fl_x=100.0, fl_y=103.0, cx=63.2, cy=41.7, k1=-0.12, k2=0.03, p1=0.002, p2=-0.001)
DIRECTIONS = [(0.0, 0.0), (0.35, 0.2), (-0.4, 0.28), (0.45, -0.3), (-0.2, -0.33)]
"""Rays (x / z, y / z; +y down the image) spread over the frame, its corners included."""


def _opencv_pixel(x, y, c):
    """Where OpenCV's radial-tangential model puts the ray (x, y, 1), written out here on its own
    (continuous pixel coordinates: the first pixel's centre at 0.5, 0.5)."""
    r2 = x * x + y * y
    radial = 1.0 + c["k1"] * r2 + c["k2"] * r2 * r2
    xd = x * radial + 2.0 * c["p1"] * x * y + c["p2"] * (r2 + 2.0 * x * x)
    yd = y * radial + c["p1"] * (r2 + 2.0 * y * y) + 2.0 * c["p2"] * x * y
    return c["fl_x"] * xd + c["cx"], c["fl_y"] * yd + c["cy"]


def _dots(centres, radius=2.5):
    """A 0/255 image with a disc at each (u, v) in continuous pixel coordinates."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    img = np.zeros((H, W), np.uint8)
    for cu, cv in centres:
        img[(u - cu) ** 2 + (v - cv) ** 2 <= radius ** 2] = 255
    return img


def _centroids(mask, centres):
    """The centroid (continuous coordinates) of the mask's pixels near each expected centre."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    out = []
    for cu, cv in centres:
        near = (mask > 0.5) & ((u - cu) ** 2 + (v - cv) ** 2 <= 36.0)
        out.append((u[near].mean(), v[near].mean()))
    return np.array(out)


def _capture(tmp_path, image, **camera):
    Image.fromarray(image).save(tmp_path / "m.png")
    frame = {"file_path": "m.png", "mask_path": "m.png", "transform_matrix": np.eye(4).tolist()}
    (tmp_path / "transforms.json").write_text(json.dumps({"w": W, "h": H, **camera, "frames": [frame]}))
    return tmp_path / "transforms.json"


def test_a_distorted_off_centre_camera_is_resampled_onto_its_pinhole_twin(tmp_path):
    """Discs drawn where the capture's lens puts five rays land, after loading, where the centred
    square-pixel pinhole camera of focal fl_x puts them (within a few tenths of a pixel)."""
    seen = _dots([_opencv_pixel(x, y, CAMERA) for x, y in DIRECTIONS])
    views = load_views(_capture(tmp_path, seen, camera_model="OPENCV", **CAMERA))
    f = CAMERA["fl_x"]
    twin = [(f * x + W / 2, f * y + H / 2) for x, y in DIRECTIONS]
    assert views.lens is not None and views.fov_x == pytest.approx(2 * np.arctan(W / 2 / f))
    np.testing.assert_allclose(_centroids(views.masks[0], twin), twin, atol=0.35)
    # read as the renderers' pinhole instead, the same discs are off by pixels: the test can fail
    plain = load_views(_capture(tmp_path, seen, fl_x=f))
    assert plain.lens is None
    assert np.abs(_centroids(plain.masks[0], twin) - twin).max() > 2.0


def test_a_pinhole_capture_is_left_alone_and_labels_stay_labels():
    assert nerfstudio_lens("PINHOLE", 100.0, 100.0, W / 2, H / 2, {"k1": 0.0}, W, H) is None
    centred = Lens("PINHOLE", (100.0, 100.0, W / 2, H / 2), W, H)  # as a COLMAP model names it
    assert centred.is_pinhole
    labels = np.random.default_rng(0).integers(0, 5, (2, H, W)).astype(np.uint8)
    np.testing.assert_array_equal(centred.resample(labels, nearest=True), labels)
    shifted = nerfstudio_lens("OPENCV", 100.0, None, W / 2 + 3.0, H / 2, {}, W, H)  # 3 px: a whole-pixel shift
    assert not shifted.is_pinhole
    moved = shifted.resample(labels, nearest=True)
    np.testing.assert_array_equal(moved[:, :, :-3], labels[:, :, 3:])
    assert set(np.unique(moved)) <= set(np.unique(labels)) and not moved[:, :, -3:].any()


def test_a_distorted_colmap_model_reads_its_masks_through_the_lens(tmp_path):
    """The same rays through pycolmap's OPENCV camera (a COLMAP model's camera) and through
    the formula above agree, so a COLMAP capture and a nerfstudio one read alike."""
    params = (CAMERA["fl_x"], CAMERA["fl_y"], CAMERA["cx"], CAMERA["cy"], CAMERA["k1"], CAMERA["k2"],
              CAMERA["p1"], CAMERA["p2"])
    lens = Lens("OPENCV", params, W, H)
    seen = _dots([_opencv_pixel(x, y, CAMERA) for x, y in DIRECTIONS]).astype(np.float32)[None] / 255
    f = CAMERA["fl_x"]
    twin = [(f * x + W / 2, f * y + H / 2) for x, y in DIRECTIONS]
    np.testing.assert_allclose(_centroids(lens.resample(seen)[0], twin), twin, atol=0.35)


@pytest.mark.parametrize("camera, match", [
    ({"fl_x": 100.0, "k4": 0.01}, "k4"),
    ({"fl_x": 100.0, "camera_model": "FOV"}, "not supported"),
    ({"fl_x": 100.0, "camera_model": "OPENCV_FISHEYE", "p1": 0.01}, "no tangential"),
    ({"cx": 70.0}, "without the focal length"),  # a photo without its camera may not name its lens
])
def test_lenses_we_cannot_read_are_refused(tmp_path, camera, match):
    image = _dots([(W / 2, H / 2)], radius=10)
    Image.fromarray(image).save(tmp_path / "m.png")
    frame = {"file_path": "m.png", "mask_path": "m.png"}
    if "fl_x" in camera:
        frame["transform_matrix"] = np.eye(4).tolist()
    (tmp_path / "transforms.json").write_text(json.dumps({"w": W, "h": H, **camera, "frames": [frame]}))
    with pytest.raises(UserError, match=match) as exc:
        load_views(tmp_path / "transforms.json")
    assert "\n" not in str(exc.value)


def test_an_object_outside_the_undistorted_frame_is_refused(tmp_path):
    corner = np.zeros((H, W), np.uint8)
    corner[:3, :3] = 255  # strong barrel distortion pulls the corners out of the pinhole twin's frame
    with pytest.raises(UserError, match="outside the undistorted image"):
        load_views(_capture(tmp_path, corner, fl_x=100.0, k1=-0.3))


def _shifted_capture(tmp_path):
    """A photo (grey ground, a brown trunk and a green crown) and its mask, seen by a camera whose
    principal point is 3 px right of the centre: its pinhole twin sees everything 3 px to the left."""
    rgb = np.full((H, W, 3), 128, np.uint8)
    rgb[50:80, 55:65] = (110, 70, 30)  # trunk
    rgb[15:50, 40:80] = (40, 140, 40)  # crown
    mask = ((rgb != 128).any(-1) * 255).astype(np.uint8)
    Image.fromarray(rgb).save(tmp_path / "photo.png")
    Image.fromarray(mask).save(tmp_path / "mask.png")
    frame = {"file_path": "photo.png", "mask_path": "mask.png", "transform_matrix": np.eye(4).tolist()}
    (tmp_path / "transforms.json").write_text(json.dumps({"w": W, "h": H, "fl_x": 100.0, "cx": W / 2 + 3.0,
                                                          "frames": [frame]}))
    return load_views(tmp_path / "transforms.json"), rgb, mask


def test_images_read_later_go_through_the_lens_like_the_masks(tmp_path, monkeypatch):
    """The GA's labels from the photo's colours, the COLMAP baseline's images and the photo the
    image-only row segments are taken through the same lens as the masks, so they stay on the object."""
    import ipm.segment
    from baselines.colmap.pipeline import make_workspace
    from ipm.methods.diff import segmented
    from ipm.methods.ga import reference_labels

    views, rgb, mask = _shifted_capture(tmp_path)
    assert views.lens is not None
    np.testing.assert_array_equal(views.masks[0][:, :-3] > 0.5, mask[:, 3:] > 127)
    labels = reference_labels(views, tree=True, source="rgb")[0]
    assert ((labels > 0) == (views.masks[0] > 0.5)).all()
    np.testing.assert_array_equal(labels[:, :-3] == 2, (rgb[:, 3:] == (40, 140, 40)).all(-1))  # crown: foliage
    ws = make_workspace(views, tmp_path / "colmap")
    seen = np.asarray(Image.open(ws.images / ws.names[0]).convert("RGB"))
    np.testing.assert_array_equal(seen[:, :-3], rgb[:, 3:])
    # a segmenter that keeps what is neither the grey ground nor past the frame: its mask lands on the mask read
    monkeypatch.setattr(ipm.segment, "mask_from_photo", lambda img: ((img != 128).any(-1) & img.any(-1)).astype(np.float32))
    cut, record = segmented(views)
    np.testing.assert_array_equal(cut.masks[0] > 0.5, views.masks[0] > 0.5)
    assert record["segmentation"]["mask_iou"] == 1.0


def test_a_twin_drawn_with_a_margin_is_distorted_as_the_capture_sees_it():
    """The inverse of reading a capture (synthesising a distorted one): discs drawn by the pinhole
    twin on a canvas grown by the lens's margin land where the capture's lens puts their rays, and
    the margin holds every ray the capture sees."""
    lens = nerfstudio_lens("OPENCV", CAMERA["fl_x"], CAMERA["fl_y"], CAMERA["cx"], CAMERA["cy"], CAMERA, W, H)
    m, f = lens.twin_margin(), CAMERA["fl_x"]
    u, v = np.meshgrid(np.arange(W + 2 * m) + 0.5, np.arange(H + 2 * m) + 0.5)
    twin = np.zeros((1, H + 2 * m, W + 2 * m), np.float32)
    for x, y in DIRECTIONS:
        twin[0][(u - (f * x + W / 2 + m)) ** 2 + (v - (f * y + H / 2 + m)) ** 2 <= 2.5 ** 2] = 1.0
    seen = lens.from_twin(twin, m)[0]
    expected = [_opencv_pixel(x, y, CAMERA) for x, y in DIRECTIONS]
    # (a disc near the frame's edge is squeezed by the barrel: its centroid lies up to 0.4 px off
    # its centre's image, against several pixels for a sign or convention error)
    np.testing.assert_allclose(_centroids(seen, expected), expected, atol=0.5)
    x, y = lens._twin_pixels_of_capture(m)
    assert x.min() >= 0 and y.min() >= 0 and x.max() <= W + 2 * m - 1 and y.max() <= H + 2 * m - 1
    assert lens._twin_pixels_of_capture(0)[0].min() < -1  # without the margin the corners fall off
    with pytest.raises(UserError, match="with its margin"):
        lens.from_twin(twin[:, 1:], m)
    # a barrel so strong at so wide a lens that its model turns back before the corners: no twin
    wide = nerfstudio_lens("OPENCV", 50.0, 50.0, W / 2, H / 2, {"k1": -0.5}, W, H)
    with pytest.raises(UserError, match="cannot be undone over its whole frame"):
        wide.twin_margin()
