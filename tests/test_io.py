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
