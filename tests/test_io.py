"""Input validation and atomic outputs (ipm.io)."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from PIL import Image

from ipm.errors import UserError
from ipm.io import atomic_dir, load_mesh, load_views


def _views(tmp_path, mask, w=32, h=32, matrix=None):
    Image.fromarray(mask.astype(np.uint8)).save(tmp_path / "m.png")
    frame = {"file_path": "m.png", "mask_path": "m.png",
             "transform_matrix": (np.eye(4) if matrix is None else matrix).tolist()}
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "w": w, "h": h, "frames": [frame]}))
    return tmp_path / "transforms.json"


def _mask(w=32, h=32):
    m = np.zeros((h, w))
    m[8:20, 10:22] = 255
    return m


def test_valid_views_load(tmp_path):
    v = load_views(_views(tmp_path, _mask()))
    assert len(v) == 1 and v.masks.shape == (1, 32, 32) and v.masks.max() == 1.0


@pytest.mark.parametrize("problem, match", [
    ("missing", "not found"),
    ("malformed", "malformed JSON"),
    ("size", "transforms.json says"),
    ("empty", "empty"),
    ("full", "all object"),
    ("nan", "NaN"),
    ("no_frames", "no frames"),
])
def test_bad_views_give_one_clear_error(tmp_path, problem, match):
    path = _views(tmp_path, _mask())
    if problem == "missing":
        path = tmp_path / "nope.json"
    elif problem == "malformed":
        path.write_text("{not json")
    elif problem == "size":
        path = _views(tmp_path, _mask(w=40))
    elif problem == "empty":
        path = _views(tmp_path, np.zeros((32, 32)))
    elif problem == "full":
        path = _views(tmp_path, np.full((32, 32), 255))
    elif problem == "nan":
        m = np.eye(4)
        m[0, 3] = np.nan
        path = _views(tmp_path, _mask(), matrix=m)
    elif problem == "no_frames":
        path.write_text(json.dumps({"camera_angle_x": 0.7, "w": 32, "h": 32, "frames": []}))
    with pytest.raises(UserError, match=match) as exc:
        load_views(path)
    assert "\n" not in str(exc.value)


def test_atomic_dir_leaves_nothing_on_failure(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with atomic_dir(out) as tmp:
            (tmp / "half.txt").write_text("x")
            raise RuntimeError("boom")
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_atomic_dir_replaces_whole_directory(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with atomic_dir(out) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]
    shutil.rmtree(out)
    assert list(tmp_path.iterdir()) == []


def test_mesh_loading_errors(tmp_path):
    with pytest.raises(UserError, match="not found"):
        load_mesh(tmp_path / "none.ply")
    (tmp_path / "bad.ply").write_text("ply\ngarbage")
    with pytest.raises(UserError):
        load_mesh(tmp_path / "bad.ply")


def _camera_file(tmp_path, **camera):
    """A one-view file with ``camera``'s fields at the top level (w/h only where given)."""
    Image.fromarray(_mask(w=40, h=30).astype(np.uint8)).save(tmp_path / "m.png")
    frame = {"file_path": "m.png", "mask_path": "m.png", "transform_matrix": np.eye(4).tolist()}
    (tmp_path / "transforms.json").write_text(json.dumps({**camera, "frames": [frame]}))
    return tmp_path / "transforms.json"


def test_nerfstudio_focal_lengths_and_image_sizes_load(tmp_path):
    """nerfstudio's fl_x/fl_y/cx/cy (top level or per frame) give the field of view; a file without
    w/h (NeRF-synthetic) takes the size from its first image."""
    focal = 0.5 * 40 / np.tan(0.35)
    v = load_views(_camera_file(tmp_path, fl_x=focal, fl_y=focal, cx=20.0, cy=15.0, w=40, h=30,
                                camera_model="OPENCV", k1=0.0))
    assert v.fov_x == pytest.approx(0.7) and (v.width, v.height) == (40, 30)
    v = load_views(_camera_file(tmp_path, camera_angle_x=0.7))
    assert (v.width, v.height) == (40, 30) and v.masks.shape == (1, 30, 40)
    data = json.loads((tmp_path / "transforms.json").read_text())
    data["frames"][0]["fl_x"] = focal  # per frame, as nerfstudio allows
    del data["camera_angle_x"]
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    assert load_views(tmp_path / "transforms.json").fov_x == pytest.approx(0.7)


@pytest.mark.parametrize("camera, match", [
    ({"w": 40, "h": 30}, "field of view is unknown"),
    ({"fl_x": 30.0, "camera_model": "SIMPLE_RADIAL", "w": 40, "h": 30}, "not supported"),
    ({"fl_x": -30.0, "w": 40, "h": 30}, "positive focal length"),
    ({"fl_x": "wide", "w": 40, "h": 30}, "invalid camera field"),
])
def test_cameras_we_cannot_read_are_refused(tmp_path, camera, match):
    with pytest.raises(UserError, match=match) as exc:
        load_views(_camera_file(tmp_path, **camera))
    assert "\n" not in str(exc.value)


def test_written_views_carry_both_focal_forms(tmp_path):
    """What we write loads here and has the fields nerfstudio's parser reads (fl_x, fl_y, cx, cy,
    w, h) beside instant-ngp's camera_angle_x, agreeing with each other. (Checked once with the
    real nerfstudio 1.1.5 ``nerfstudio-data`` parser on Debian's CPU torch: a written file loads
    with cameras and masks equal to ours; without fl_x/fl_y, w/h or cx/cy it fails; it never
    reads camera_angle_x.)"""
    from ipm.io import write_views

    Image.fromarray(_mask(w=40, h=30).astype(np.uint8)).save(tmp_path / "m.png")
    write_views(tmp_path / "transforms.json", 0.7, 40, 30,
                [{"file_path": "m.png", "mask_path": "m.png", "transform_matrix": np.eye(4)}])
    data = json.loads((tmp_path / "transforms.json").read_text())
    assert {"fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x"} <= set(data)
    assert 2 * np.arctan(0.5 * data["w"] / data["fl_x"]) == pytest.approx(data["camera_angle_x"])
    assert (data["cx"], data["cy"]) == (20.0, 15.0)
    del data["camera_angle_x"]
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    assert load_views(tmp_path / "transforms.json").fov_x == pytest.approx(0.7)


def test_masks_come_from_the_alpha_channel_when_no_mask_path(tmp_path):
    """A frame without mask_path takes its mask from its image's alpha channel (the file_path
    named without its extension, as NeRF-synthetic does); an image without one is segmented by
    its colours (``ipm.segment``), and refused when nothing stands out from its border."""
    rgba = np.zeros((30, 40, 4), np.uint8)
    rgba[..., :3] = 200  # a grey photo: the colour says nothing, the alpha says where the object is
    rgba[..., 3] = _mask(w=40, h=30)
    Image.fromarray(rgba).save(tmp_path / "r_0.png")
    frame = {"file_path": "r_0", "transform_matrix": np.eye(4).tolist()}
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [frame]}))
    v = load_views(tmp_path / "transforms.json")
    np.testing.assert_array_equal(v.masks[0], _mask(w=40, h=30) > 127)
    Image.fromarray(rgba[..., :3]).save(tmp_path / "r_0.png")
    with pytest.raises(UserError, match="no alpha channel, and no object stands out"):
        load_views(tmp_path / "transforms.json")
    rgba[_mask(w=40, h=30) > 127, :3] = (200, 60, 40)
    Image.fromarray(rgba[..., :3]).save(tmp_path / "r_0.png")
    found = load_views(tmp_path / "transforms.json").masks[0] > 0.5
    assert (found != (_mask(w=40, h=30) > 127)).sum() <= 4  # the speck removal rounds the four corners
    frame.pop("file_path")
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "w": 40, "h": 30, "frames": [frame]}))
    with pytest.raises(UserError, match="no mask_path"):
        load_views(tmp_path / "transforms.json")
