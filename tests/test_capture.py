"""Captures in other frames and formats (``ipm.capture``): a z-up transforms.json and a COLMAP
sparse model come back in the scene convention (y up, the object's foot at y = 0) and reconstruct."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from ipm.capture import ground_height, open_views, read_colmap, rotation_to_y, upright
from ipm.errors import UserError
from ipm.io import load_views
from ipm.render.cameras import gl_to_colmap
from tests.conftest import synthesized
from tests.test_cli import _one_line_error, ipm

Y_TO_Z = np.array([[1.0, 0, 0, 0.3], [0, 0, -1, -0.2], [0, 1, 0, 0.5], [0, 0, 0, 1]])
"""A z-up world: the convention's y turned to z (a quarter turn about x), then shifted."""


@pytest.fixture(scope="module")
def cup_views(tmp_path_factory, mitsuba_cpu):
    """cup_1 seen from 6 views at 64 px (the input view and five on the hemisphere)."""
    return synthesized(tmp_path_factory, "cup_1", n_views=6, res=64, spp=4)


def _z_up_file(case, out):
    """``case``'s transforms.json with every camera moved into the z-up world, masks by absolute path."""
    data = json.loads((case / "transforms.json").read_text())
    for fr in data["frames"]:
        fr["transform_matrix"] = (Y_TO_Z @ np.asarray(fr["transform_matrix"])).tolist()
        fr["mask_path"] = str(case / fr["mask_path"])
        fr.pop("semantic_path", None)
    out.mkdir(parents=True, exist_ok=True)
    (out / "transforms.json").write_text(json.dumps(data))
    return out / "transforms.json"


@pytest.mark.parametrize("up", [(0, 1, 0), (0, -1, 0), (0, 0, 1), (1, 0, 0), (0.3, -0.5, 0.8)])
def test_rotation_to_y(up):
    r = rotation_to_y(np.array(up))
    np.testing.assert_allclose(r @ (np.array(up) / np.linalg.norm(up)), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize("up", ["z", "auto"])
def test_a_z_up_capture_comes_back_upright(tmp_path, cup_views, up):
    """The cameras come back turned as they were, shifted as one rigid body; the ground found from
    the masks lies at or somewhat below the cup's foot (a base seen from above hides what is
    under it), never above it."""
    truth = load_views(cup_views / "transforms.json")
    views = open_views(_z_up_file(cup_views, tmp_path), up=up)
    assert not views.ground_known and views.masks.shape == truth.masks.shape
    tol = 1e-9 if up == "z" else 1e-6  # auto: level cameras tell it exactly
    np.testing.assert_allclose(views.c2w[:, :3, :3], truth.c2w[:, :3, :3], atol=tol)
    if up == "z":
        shift = views.c2w[:, :3, 3] - truth.c2w[:, :3, 3]
        np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-9)
        height = 0.855  # cup_1's height (its reference mesh)
        assert -0.3 * height < -shift[0, 1] <= 0.02 * height  # the ground in the truth's frame
        back = views.world_from_input @ Y_TO_Z  # the truth's world to ours: the same shift
        np.testing.assert_allclose(back[:3, :3], np.eye(3), atol=1e-12)
        np.testing.assert_allclose(back[:3, 3], shift[0], atol=1e-9)
    assert upright(truth, "y") is truth and ground_height(truth.first(1)) == 0.0


def test_unknown_or_unknowable_up_axis_is_refused(cup_views):
    with pytest.raises(UserError, match="unknown up axis 'w'"):
        open_views(cup_views / "transforms.json", up="w")
    with pytest.raises(UserError, match="cannot tell the world's up axis"):  # one view: its tilt is open
        upright(load_views(cup_views / "transforms.json").first(1), "auto")


def _colmap_model(case, out, model="PINHOLE", params=None, mask_names="colmap"):
    """``case``'s views as a COLMAP sparse model in a z-up world: out/sparse, out/images, out/masks."""
    import pycolmap

    views = load_views(case / "transforms.json")
    f = 0.5 * views.width / np.tan(0.5 * views.fov_x)
    params = [f, f, views.width / 2, views.height / 2] if params is None else params
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=views.width, height=views.height,
                                                    params=params, camera_id=1))
    for d in ("sparse", "images", "masks"):
        (out / d).mkdir(parents=True, exist_ok=True)
    for i, fr in enumerate(views.frames):
        name = f"photo_{i:02d}.jpg"
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=i + 1),
                                         pycolmap.Rigid3d(gl_to_colmap(Y_TO_Z @ views.c2w[i])))
        shutil.copyfile(case / fr["file_path"], out / "images" / name)
        mask = f"{name}.png" if mask_names == "colmap" else f"photo_{i:02d}.png"
        shutil.copyfile(case / fr["mask_path"], out / "masks" / mask)
    rec.write(str(out / "sparse"))
    return out


@pytest.mark.parametrize("mask_names", ["colmap", "stem"])
def test_a_colmap_model_reads_like_its_transforms_file(tmp_path, cup_views, mask_names):
    truth = load_views(cup_views / "transforms.json")
    m = _colmap_model(cup_views, tmp_path, mask_names=mask_names)
    views = read_colmap(m / "sparse", m / "images", m / "masks", up="z")
    assert views.fov_x == pytest.approx(truth.fov_x) and (views.width, views.height) == (truth.width, truth.height)
    np.testing.assert_allclose(views.c2w[:, :3, :3], truth.c2w[:, :3, :3], atol=1e-9)
    np.testing.assert_array_equal(views.masks, truth.masks)
    assert all(fr["file_path"].endswith(f"photo_{i:02d}.jpg") for i, fr in enumerate(views.frames))
    auto = open_views(colmap=m / "sparse", images=m / "images", masks=m / "masks")  # up: auto for COLMAP
    np.testing.assert_allclose(auto.c2w[:, :3, :3], truth.c2w[:, :3, :3], atol=1e-6)
    segmented = open_views(colmap=m / "sparse", images=m / "images")  # no masks: from the photos' colours
    iou = (segmented.masks * truth.masks).sum() / np.maximum(segmented.masks, truth.masks).sum()
    assert iou > 0.9


def test_a_distorted_off_centre_colmap_model_reads_through_its_lens(tmp_path, cup_views):
    """A COLMAP model whose camera has radial distortion and an off-centre principal point,
    its masks drawn through that lens from the truth's: they come back as the truth's pinhole
    camera sees them (up to the two resamplings' edge pixels: IoU 0.97-0.99 at 64 px, against
    0.66-0.72 for the masks as drawn)."""
    import pycolmap
    from PIL import Image

    truth = load_views(cup_views / "transforms.json")
    w, h = truth.width, truth.height
    f = 0.5 * w / np.tan(0.5 * truth.fov_x)
    params = [f, w / 2 + 2.6, h / 2 - 1.8, -0.08]  # SIMPLE_RADIAL: f, cx, cy, k
    m = _colmap_model(cup_views, tmp_path, model="SIMPLE_RADIAL", params=params)
    lens = pycolmap.Camera(model="SIMPLE_RADIAL", width=w, height=h, params=params)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = lens.cam_from_img(np.stack([cols.ravel(), rows.ravel()], -1))  # each captured pixel's ray
    c = np.clip(np.floor(f * rays[:, 0] + w / 2), 0, w - 1).astype(int)
    r = np.clip(np.floor(f * rays[:, 1] + h / 2), 0, h - 1).astype(int)
    for i, mask in enumerate(truth.masks):
        drawn = (mask[r, c].reshape(h, w) * 255).astype(np.uint8)
        Image.fromarray(drawn).save(m / "masks" / f"photo_{i:02d}.jpg.png")
    views = read_colmap(m / "sparse", m / "images", m / "masks", up="z")
    assert views.lens is not None and views.fov_x == pytest.approx(truth.fov_x)
    iou = (views.masks * truth.masks).sum((1, 2)) / np.maximum(views.masks, truth.masks).sum((1, 2))
    assert iou.min() > 0.95
    # the masks as drawn, taken for the pinhole's, are further off: the test can fail
    raw = np.stack([np.asarray(Image.open(m / "masks" / f"photo_{i:02d}.jpg.png")) > 127 for i in range(len(truth))])
    assert ((raw * truth.masks).sum((1, 2)) / np.maximum(raw, truth.masks).sum((1, 2))).min() < iou.min() - 0.02


@pytest.mark.parametrize("problem, match", [
    ("no_mask", "no mask for COLMAP image"), ("no_model", "cannot read the COLMAP"),
    ("not_perspective", "not a perspective camera"), ("both", "give one of --views"),
    ("no_images", "--colmap needs --images")])
def test_colmap_input_problems_are_clear(tmp_path, cup_views, problem, match):
    kw = {}
    if problem == "not_perspective":
        kw = dict(model="EQUIRECTANGULAR", params=[64.0, 64.0])
    m = _colmap_model(cup_views, tmp_path, **kw)
    if problem == "no_mask":
        (m / "masks" / "photo_03.jpg.png").unlink()
    if problem == "no_model":
        shutil.rmtree(m / "sparse")
        (m / "sparse").mkdir()
    args = dict(colmap=m / "sparse", images=m / "images", masks=m / "masks")
    if problem == "both":
        args["views"] = cup_views / "transforms.json"
    if problem == "no_images":
        args["images"] = None
    with pytest.raises(UserError, match=match):
        open_views(**args)


@pytest.mark.slow
def test_z_up_and_colmap_inputs_reconstruct(tmp_path, cup_views):
    """Smoke profile through the command line: a z-up transforms.json with --up z and a COLMAP
    model; the params say how to take the mesh back to the input's world."""
    m = _colmap_model(cup_views, tmp_path / "colmap")
    runs = {"z_up": ["--views", str(_z_up_file(cup_views, tmp_path / "zup")), "--up", "z"],
            "colmap": ["--colmap", str(m / "sparse"), "--images", str(m / "images"), "--masks", str(m / "masks")]}
    for name, args in runs.items():
        out = tmp_path / f"out_{name}"
        res = ipm("reconstruct", "--generator", "dishes", *args, "--out", str(out), "--profile", "smoke",
                  "--n-input-views", "2", "--quiet", "--threads", "2")
        assert res.returncode == 0, res.stderr
        info = json.loads((out / "params.json").read_text())
        back = np.asarray(info["world_from_input"])
        np.testing.assert_allclose(back[:3, :3] @ Y_TO_Z[:3, :3], np.eye(3), atol=1e-6)
        assert (out / "mesh.glb").is_file()
        if name == "z_up":  # its frames name colour images it does not have: the fit stands, unpainted
            assert "cannot read colour image" in info["texture"]["skipped"] and not (out / "textures").exists()
        else:  # COLMAP's images are the colour views (their light unknown): painted as seen
            assert info["texture"]["lighting"] is None and (out / "textures" / "body.png").is_file()
    res = ipm("reconstruct", "--generator", "dishes", "--colmap", str(m / "sparse"), "--masks", str(m / "masks"),
              "--out", str(tmp_path / "bad"), "--profile", "smoke")
    assert "--colmap needs --images" in _one_line_error(res) and not (tmp_path / "bad").exists()


@pytest.mark.slow
def test_a_nerfstudio_file_with_alpha_masks_reconstructs(tmp_path, cup_views):
    """nerfstudio's fields (fl_x, fl_y, cx, cy per frame, no camera_angle_x, no w/h) and RGBA
    photos whose alpha is the mask (no mask_path): loads as the original and reconstructs."""
    from PIL import Image

    data = json.loads((cup_views / "transforms.json").read_text())
    f = 0.5 * data["w"] / np.tan(0.5 * data["camera_angle_x"])
    frames = []
    for i, fr in enumerate(data["frames"][:2]):
        rgb = np.asarray(Image.open(cup_views / fr["file_path"]).convert("RGB"))
        alpha = np.asarray(Image.open(cup_views / fr["mask_path"]))
        Image.fromarray(np.dstack([rgb, alpha])).save(tmp_path / f"r_{i}.png")
        frames.append({"file_path": f"r_{i}", "transform_matrix": fr["transform_matrix"], "fl_x": f, "fl_y": f,
                       "cx": data["w"] / 2, "cy": data["h"] / 2, "camera_model": "OPENCV", "k1": 0.0})
    (tmp_path / "transforms.json").write_text(json.dumps({"frames": frames}))
    views, truth = load_views(tmp_path / "transforms.json"), load_views(cup_views / "transforms.json").first(2)
    np.testing.assert_array_equal(views.masks, truth.masks)
    assert views.fov_x == pytest.approx(truth.fov_x) and views.width == truth.width
    out = tmp_path / "out"
    res = ipm("reconstruct", "--generator", "dishes", "--views", str(tmp_path / "transforms.json"), "--out", str(out),
              "--profile", "smoke", "--quiet", "--threads", "2")
    assert res.returncode == 0, res.stderr
    assert (out / "mesh.glb").is_file() and "world_from_input" not in json.loads((out / "params.json").read_text())
