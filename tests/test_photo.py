"""A photo without a camera (``ipm.photo``): the camera's genes move vertices so that the fixed
render camera sees what the estimated camera would; the camera comes back from a silhouette."""
from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

from ipm.capture import open_views
from ipm.errors import UserError
from ipm.io import load_views
from ipm.photo import DEFAULT_FOV, UnknownCamera, c2w, fov_of, photo_views
from ipm.render.cameras import project


@pytest.mark.parametrize("genes", [(0.3, 0.0, 0.0), (0.1, 0.15, 0.4), (1.0, -0.3, -0.5)])
def test_the_render_camera_sees_mapped_points_where_the_camera_sees_them(genes, rng):
    """Exact for any point in front of the camera: pitch, roll and focal length are a rotation
    about the camera centre and a scaling of the camera's image axes."""
    cam = UnknownCamera(pitch0=0.5, fov0=np.radians(50.0), fov_known=False)
    pts = np.array([0.0, 0.0, -3.0]) + rng.normal(0, 0.7, (50, 3))
    pts[:, 1] = np.abs(pts[:, 1])
    true_px = project(pts, c2w(genes[0], genes[1]), fov_of(genes[2], cam.fov0), 200, 150)
    mapped = np.asarray(cam.to_render(jnp.asarray(pts), jnp.asarray(genes)))
    np.testing.assert_allclose(project(mapped, c2w(cam.pitch0), cam.fov0, 200, 150), true_px, atol=1e-3)  # float32


def test_camera_genes_have_gradients():
    cam = UnknownCamera(pitch0=0.5, fov0=np.radians(50.0), fov_known=True)
    lo, hi = cam.bounds()
    assert lo[2] == hi[2] == 0.0 and lo[0] < 0 < 0.5 < hi[0]  # a given FOV stays put
    g = jax.grad(lambda genes: cam.to_render(jnp.ones((1, 3)), genes).sum())(jnp.array([0.4, 0.1, 0.2]))
    assert np.all(np.isfinite(g)) and np.all(np.asarray(g) != 0)


def test_a_photo_loads_with_an_unknown_camera(tmp_path, tiny_case):
    data = json.loads((tiny_case / "transforms.json").read_text())
    frame = data["frames"][0]
    views = photo_views(tiny_case / frame["file_path"], tiny_case / frame["mask_path"], fov_deg=40.0)
    truth = load_views(tiny_case / "transforms.json")
    np.testing.assert_array_equal(views.masks, truth.masks[:1])
    assert views.camera.fov_known and views.fov_x == pytest.approx(np.radians(40.0)) and len(views) == 1
    # the same as a transforms.json frame without transform_matrix (and without a field of view)
    del frame["transform_matrix"], data["camera_angle_x"], data["fl_x"], data["fl_y"]
    frame["mask_path"] = str(tiny_case / frame["mask_path"])
    data["frames"] = [frame]
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    views = open_views(tmp_path / "transforms.json")
    assert not views.camera.fov_known and views.fov_x == pytest.approx(DEFAULT_FOV)
    # an RGBA photo brings its own mask
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[20:50, 25:40] = 255
    Image.fromarray(rgba).save(tmp_path / "photo.png")
    assert open_views(image=tmp_path / "photo.png").masks.sum() == 30 * 15


@pytest.mark.parametrize("problem, match", [
    ("no_image", "image not found"), ("bad_fov", "--fov: needs 1 to 170"),
    ("two_frames", "an unknown camera needs exactly one view"), ("up", "--up does not apply"),
    ("segment_views", "--segment go with --image"), ("segment_name", "unknown segmenter 'grabcut'")])
def test_photo_input_problems_are_clear(tmp_path, tiny_case, problem, match):
    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    args = dict(image=tiny_case / frame["file_path"], mask=tiny_case / frame["mask_path"])
    if problem == "no_image":
        args["image"] = tmp_path / "none.png"
    if problem == "bad_fov":
        args["fov"] = float("nan")
    if problem == "up":
        args["up"] = "z"
    if problem == "segment_views":
        args = dict(views=tiny_case / "transforms.json", segment="learned")
    if problem == "segment_name":
        args = dict(image=tiny_case / frame["file_path"], segment="grabcut")
    if problem == "two_frames":
        data = json.loads((tiny_case / "transforms.json").read_text())
        for fr in data["frames"]:
            del fr["transform_matrix"]
            fr["mask_path"] = str(tiny_case / fr["mask_path"])
        (tmp_path / "transforms.json").write_text(json.dumps(data))
        args = dict(views=tmp_path / "transforms.json")
    with pytest.raises(UserError, match=match):
        open_views(**args)


def test_masks_from_the_image_on_a_plain_background(tiny_case, rng):
    """The textured, lit reference render on its plain background: the colour model of the border
    finds the object (edge pixels aside), also with sensor noise and with the object cut by the
    image's bottom edge (the border model then refits without the object's pixels)."""
    from ipm.segment import mask_from_image

    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    rgb = np.asarray(Image.open(tiny_case / frame["file_path"]))[..., :3]
    truth = np.asarray(Image.open(tiny_case / frame["mask_path"])) > 127
    iou = lambda m: ((m > 0.5) & truth).sum() / ((m > 0.5) | truth).sum()  # noqa: E731
    assert iou(mask_from_image(rgb)) > 0.93
    noisy = np.clip(rgb + rng.normal(0, 4, rgb.shape), 0, 255).astype(np.uint8)
    assert iou(mask_from_image(noisy)) > 0.9
    low = np.nonzero(truth.any(1))[0].max()
    cut = mask_from_image(np.roll(rgb, 63 - low, axis=0))
    truth = np.roll(truth, 63 - low, axis=0)
    assert iou(cut) > 0.9 and truth[-1].any()


@pytest.mark.slow
def test_a_bare_photo_reconstructs(tmp_path, tiny_case):
    """Smoke profile through the command line: one photo, no mask (segmented), no camera: the
    params carry the estimated camera."""
    from tests.test_cli import ipm

    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    out = tmp_path / "out"
    res = ipm("reconstruct", "--generator", "dishes", "--image", str(tiny_case / frame["file_path"]), "--out",
              str(out), "--profile", "smoke", "--quiet", "--threads", "2")
    assert res.returncode == 0, res.stderr
    camera = json.loads((out / "params.json").read_text())["camera"]
    assert -20 <= camera["pitch_deg"] <= 85 and 15 <= camera["fov_x_deg"] <= 100 and not camera["fov_given"]
    assert np.asarray(camera["transform_matrix"]).shape == (4, 4) and (out / "mesh.glb").is_file()
    assert camera["proposed"] and "(proposed by the learned regressor)" in res.stdout  # the grid's: the next test
    res = ipm("reconstruct", "--generator", "trees", "--method", "ga", "--image", str(tiny_case / frame["file_path"]),
              "--out", str(tmp_path / "ga"), "--profile", "smoke")
    assert res.returncode != 0 and "diff path estimates it" in res.stderr and not (tmp_path / "ga").exists()


def test_registration_keeps_the_ground_and_the_vertical():
    """The similarity takes the estimated camera's centre to the given one and its heading to the
    given heading, the ground to the ground, and turns only about the vertical; with the pitch
    and roll right it keeps every pixel's ray."""
    from ipm.photo import EYE, camera_errors, heading, placed_pose, registration
    from ipm.render.cameras import look_at

    given = look_at([2.0, 1.5, 3.0], [0.0, 0.3, 0.0])
    errors = camera_errors({"pitch_deg": 0.0, "roll_deg": 0.0, "fov_x_deg": 40.0}, given, np.radians(40.0))
    pitch = -np.radians(errors["pitch_deg"])
    camera = {"transform_matrix": c2w(pitch).tolist(), "pitch_deg": np.degrees(pitch), "roll_deg": 0.0, "fov_x_deg": 40}
    assert camera_errors(camera, given, np.radians(40.0)) == pytest.approx({"pitch_deg": 0, "roll_deg": 0, "fov_rel": 0},
                                                                         abs=1e-9)
    for tilt in (0.0, 0.1):  # a pitch error still keeps the ground and the vertical
        m = registration({**camera, "transform_matrix": c2w(pitch + tilt, 0.05 * tilt).tolist()}, given)
        np.testing.assert_allclose(m[:3, :3] @ EYE + m[:3, 3], given[:3, 3], atol=1e-9)
        ground = np.array([[0.3, 0.0, -2.0], [-1.0, 0.0, -4.0], [2.0, 0.0, -1.0]])
        np.testing.assert_allclose((ground @ m[:3, :3].T + m[:3, 3])[:, 1], 0.0, atol=1e-9)
        np.testing.assert_allclose(m[:3, 1], [0.0, 1.5, 0.0], atol=1e-9)  # the vertical stays vertical
    m = registration(camera, given)
    assert heading(m @ np.asarray(camera["transform_matrix"])) == pytest.approx(heading(given))
    pts = np.array([[0.1, 0.4, -2.5], [0.5, 0.2, -3.0]])
    np.testing.assert_allclose(project(pts @ m[:3, :3].T + m[:3, 3], given, 0.7, 64, 48),
                               project(pts, c2w(pitch), 0.7, 64, 48), atol=1e-9)
    pose = placed_pose({"yaw": 0.2, "translation": [0.0, 0.0, -3.0], "scale": 0.5}, m)
    assert pose["translation"][1] == pytest.approx(0.0, abs=1e-9) and pose["scale"] == pytest.approx(0.5 * 1.5)


def test_a_camera_error_moves_a_perfect_shape_along_the_foot_ray():
    """``misplaced``: no error, no move; a pitch and field-of-view error keep the foot on its pixel
    under the wrong camera, the ground on the ground and the object's size in the image."""
    from ipm.photo import misplaced
    from ipm.render.cameras import look_at

    given, fov, w, h = look_at([0.0, 1.2, 3.0], [0.0, 0.3, 0.0]), 0.7, 64, 48
    pts = np.array([[0.0, 0.0, 0.3], [0.05, 0.0, 0.3], [0.0, 0.4, 0.0], [-0.2, 0.0, -0.2]])
    foot = tuple(project(pts[:1], given, fov, w, h)[0])
    np.testing.assert_allclose(misplaced(pts, given, fov, w, h, foot), pts, atol=1e-12)
    c, s = np.cos(0.03), np.sin(0.03)
    wrong = given.copy()
    wrong[:3, :3] = given[:3, :3] @ np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    moved = misplaced(pts, given, fov, w, h, foot, d_pitch=0.03, fov_rel=0.1)
    assert np.linalg.norm(moved[0] - pts[0]) > 0.05  # farther along the ground
    np.testing.assert_allclose(project(moved[:1], wrong, 1.1 * fov, w, h)[0], foot, atol=1e-9)
    np.testing.assert_allclose(moved[[0, 1, 3], 1], 0.0, atol=1e-12)
    size = lambda p, cam, f: np.linalg.norm(np.diff(project(p[:2], cam, f, w, h), axis=0))  # noqa: E731
    assert size(moved, wrong, 1.1 * fov) == pytest.approx(size(pts, given, fov), rel=0.02)


@pytest.mark.slow
def test_the_camera_withheld_benchmark_row(tmp_path, tiny_case):
    """``photo``: view 0's mask without its camera; the search from the learned camera's proposal
    (the default ``camera_start``), the result placed in the views' world for scoring, with the
    camera's errors recorded."""
    from ipm.methods import METHODS
    from ipm.photo import placed_pose, registration

    info = METHODS["photo"](tiny_case / "transforms.json", tmp_path / "out", generator="dishes", profile="smoke",
                            progress=False)
    assert set(info["camera_error"]) == {"pitch_deg", "roll_deg", "fov_rel"} and info["method"] == "photo"
    assert (tmp_path / "out" / "mesh.ply").is_file() and info["pose"] != info["photo_pose"]
    trace = (tmp_path / "out" / "trace.csv").read_text().splitlines()
    assert info["camera"]["proposed"] and any(row.split(",")[3] == "learned" for row in trace)
    assert not any(row.startswith("focal,") for row in trace)  # the proposed field of view is held
    place = registration(info["camera"], load_views(tiny_case / "transforms.json").c2w[0])
    assert info["pose"] == placed_pose(info["photo_pose"], place)


@pytest.mark.slow
def test_the_field_of_view_given_row(tmp_path, tiny_case, monkeypatch):
    """``photo_fov``: view 0's mask with its field of view but not its camera; the field of view
    stays the given one, and the memetic stage runs free, then once per pitch start with the
    camera's pitch held there (starts, steps and the last generation; only when it is given)."""
    import pandas as pd

    import ipm.search.loop as loop
    from ipm.generators import get_generator
    from ipm.methods import METHODS
    from ipm.problem import POSE_NAMES
    from ipm.profiles import get_profile

    ip = len(get_generator("dishes").spec) + len(POSE_NAMES)  # the pitch gene
    runs, real = [], loop.memetic

    def spy(initial, evaluate, clip, *args, **kwargs):
        out = real(initial, evaluate, clip, *args, **kwargs)
        runs.append(sorted({round(float(np.degrees(i.z[ip])), 6) for i in initial}
                           | {round(float(np.degrees(i.best_z[ip])), 6) for i in out}))
        return out

    monkeypatch.setattr(loop, "memetic", spy)
    info = METHODS["photo_fov"](tiny_case / "transforms.json", tmp_path / "out", generator="dishes",
                                profile="smoke", progress=False, pitch_starts=(10.0, 30.0, 50.0), camera_start="prior")
    assert info["method"] == "photo_fov" and info["camera_error"]["fov_rel"] == pytest.approx(0.0, abs=1e-6)
    assert info["camera"]["fov_given"] and len(runs) == 4  # a free run and one per pitch start
    assert len(runs[0]) > 1 and runs[1:] == [[10.0], [30.0], [50.0]]
    METHODS["photo"](tiny_case / "transforms.json", tmp_path / "bare", generator="dishes", profile="smoke",
                     progress=False, pitch_starts=(10.0, 30.0, 50.0), focal_sweep=1, focal_steps=2,
                     camera_start="prior")
    assert len(runs) == 5  # without the field of view: one memetic stage
    focal = pd.read_csv(tmp_path / "bare" / "trace.csv").query("stage == 'focal'")
    assert len(focal) and set(focal["res"]) == {get_profile("smoke").loop.refine_res[-1]}  # its steps' size too


@pytest.mark.slow
def test_a_field_of_view_grid_keeps_the_fit_of_lowest_loss(tmp_path, tiny_case, monkeypatch):
    """``fov_grid``: with the field of view withheld, one fit per grid value with it held (pitch
    starts too), the lowest score kept and reported as chosen, not given; each value's score in
    the trace."""
    import pandas as pd

    import ipm.methods.diff as diff
    from ipm.methods import METHODS

    held, real = [], diff.fit_at_fov

    def spy(views, generator, prof, seed, progress, fov_deg):
        out = real(views, generator, prof, seed, progress, fov_deg)
        held.append((fov_deg, out[0].camera.fov_known, float(np.degrees(out[0].camera.fov0)), out[3]))
        return out

    monkeypatch.setattr(diff, "fit_at_fov", spy)
    info = METHODS["photo"](tiny_case / "transforms.json", tmp_path / "out", generator="dishes", profile="smoke",
                            progress=False, fov_grid=(30.0, 55.0))
    assert [(f, known) for f, known, *_ in held] == [(30.0, True), (55.0, True)]
    assert all(f == pytest.approx(f0) for f, _, f0, _ in held)
    kept = min(held, key=lambda h: h[3])
    camera = info["camera"]
    assert camera["fov_x_deg"] == pytest.approx(kept[0]) and camera["fov_from_grid"] and not camera["fov_given"]
    trace = pd.read_csv(tmp_path / "out" / "trace.csv")
    grid = trace[trace.stage == "fov grid"]
    assert list(grid.origin) == ["fov=30", "fov=55"] and np.allclose(grid.loss, [h[3] for h in held])
    assert np.isfinite(info["final_loss"])
    # the field of view given: no grid
    held.clear()
    METHODS["photo_fov"](tiny_case / "transforms.json", tmp_path / "given", generator="dishes", profile="smoke",
                         progress=False, fov_grid=(30.0, 55.0))
    assert held == []


@pytest.mark.parametrize("values, match", [
    (["nan"], "diff setting fov_grid must be a finite number, got nan"),
    (["0.5", "40"], "diff setting fov_grid must be >= 1 and <= 170, got 0.5"),
    (None, "--fov-grid applies to the diff path only")])
def test_fov_grid_problems_are_one_line(tmp_path, tiny_case, capsys, values, match):
    from ipm.cli import main

    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    argv = ["reconstruct", "--generator", "dishes", "--image", str(tiny_case / frame["file_path"]),
            "--mask", str(tiny_case / frame["mask_path"]), "--out", str(tmp_path / "out"), "--quiet",
            "--fov-grid", *(values or [])]
    if values is None:
        argv += ["--method", "ga"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1 and not (tmp_path / "out").exists()


def test_holding_closes_the_bounds_and_gives_them_back():
    from ipm.generators import get_generator
    from ipm.problem import Problem

    cam = UnknownCamera(pitch0=0.5, fov0=np.radians(50.0), fov_known=False, foot=(32.0, 60.0, 64, 64))
    problem = Problem(get_generator("dishes"), np.array([0.0, 0.0, -3.0]), 1.0, camera=cam)
    i = problem.camera_gene("pitch")
    lower, upper = problem.lower.copy(), problem.upper.copy()
    gen = problem.generator
    z = problem.initial_z(gen.spec.to_unit(next(iter(gen.presets.values()))), 0.3)
    with pytest.raises(RuntimeError), problem.holding({i: 0.25}):
        assert problem.clip(z)[i] == 0.25 and np.all(np.delete(problem.clip(z) == z, i))
        raise RuntimeError
    np.testing.assert_array_equal(problem.lower, lower)
    np.testing.assert_array_equal(problem.upper, upper)


@pytest.mark.parametrize("unknown", [False, True])
def test_to_world_maps_points_as_the_vertex_program_does(unknown, rng):
    """``Problem.to_world`` works the pose out once per map; each call equals, to the bit, the map
    that works it out again, and the compiled vertex program places the generator's vertices there."""
    from ipm.generators import get_generator
    from ipm.problem import Problem, _world_maps

    cam = UnknownCamera(pitch0=0.5, fov0=np.radians(50.0), fov_known=False, foot=(32.0, 60.0, 64, 64))
    problem = Problem(get_generator("dishes"), np.array([0.0, 0.0, -3.0]), 1.0, camera=cam if unknown else None)
    gen = problem.generator
    z = problem.initial_z(gen.spec.to_unit(gen.presets["mug"]), 0.7)
    z[problem.n_shape + 1:] += rng.uniform(-0.05, 0.05, len(z) - problem.n_shape - 1)  # tilts, moves, camera
    z = problem.clip(z)
    world, pose = _world_maps(problem.n_shape, problem._camera_kind, True)
    zj, c, points = jnp.asarray(z, jnp.float32), jnp.asarray(problem.constants()), rng.normal(size=(5, 3))
    for v in (points[:1], points):
        vj = jnp.asarray(v, jnp.float32)
        np.testing.assert_array_equal(problem.to_world(z)(v), np.asarray(world(vj, zj, c, pose(zj, c)), np.float64))
        np.testing.assert_array_equal(problem.to_world(z)(v), np.asarray(world(vj, zj, c), np.float64))
    x = gen.spec.from_unit(z[:problem.n_shape])
    placed = np.asarray(problem.vertex_fn(problem.key(z), 0)(z)).reshape(-1, 3)
    np.testing.assert_allclose(problem.to_world(z)(gen.mesh(x, 0).vertices), placed, atol=1e-5)


@pytest.mark.parametrize("genes", [(0.2, 0.0, 0.0), (0.7, 0.1, 0.3), (0.45, -0.2, -0.4)])
def test_the_object_rides_on_the_foot_ray(genes):
    """Whatever the camera's genes, the ground point under the object lies on the mask's foot
    pixel, and the size factor keeps a thing's image size: a camera step does not move the object
    in the image (so Adam can turn the camera without dragging the pose along)."""
    cam = UnknownCamera(pitch0=0.5, fov0=np.radians(50.0), fov_known=False, foot=(30.5, 50.0, 64, 48))
    here, base, ratio = cam.placement(np.array(genes))
    fov = fov_of(genes[2], cam.fov0)
    np.testing.assert_allclose(project(here[None], c2w(genes[0], genes[1]), fov, 64, 48)[0], (30.5, 50.0), atol=1e-9)
    assert here[1] == pytest.approx(0.0) and base[1] == pytest.approx(0.0)
    f, f0 = 0.5 * 64 / np.tan(0.5 * fov), 0.5 * 64 / np.tan(0.5 * cam.fov0)
    size = ratio * f / np.linalg.norm(here - np.array([0, 1, 0]))  # image size of a thing `ratio` big at `here`
    assert size == pytest.approx(f0 / np.linalg.norm(base - np.array([0, 1, 0])))


def test_the_field_of_view_comes_from_exif(tmp_path):
    """A phone photo's Exif 35 mm equivalent focal length gives its field of view (26 mm: a
    main camera, 69 degrees across the long side of a 3:2 frame); --fov still wins."""
    from ipm.photo import exif_fov

    assert np.degrees(exif_fov(26.0, 300, 200)) == pytest.approx(69.4, abs=0.1)
    assert np.degrees(exif_fov(26.0, 200, 300)) == pytest.approx(49.6, abs=0.1)
    rgb = np.full((200, 300, 3), 128, np.uint8)
    rgb[60:160, 120:180] = (200, 40, 30)
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 26
    Image.fromarray(rgb).save(tmp_path / "phone.jpg", exif=exif, quality=95)
    views = photo_views(tmp_path / "phone.jpg")
    assert views.camera.fov_known and np.degrees(views.fov_x) == pytest.approx(69.4, abs=0.1)
    assert np.degrees(photo_views(tmp_path / "phone.jpg", fov_deg=40.0).fov_x) == pytest.approx(40.0)
    Image.fromarray(rgb).save(tmp_path / "plain.jpg", quality=95)
    assert not photo_views(tmp_path / "plain.jpg").camera.fov_known


def test_the_focal_sweep_finds_the_lowest_loss_over_the_field_of_view():
    """``sweep_focal`` holds the focal gene at each grid point while the rest moves (each point
    starting from its inner neighbour's result) and keeps the point of lowest loss; with the field
    of view given it does nothing."""
    from dataclasses import replace

    from ipm.generators import get_generator
    from ipm.search.moves import MOVES
    from ipm.search.moves.camera import CameraSettings, sweep_focal
    from ipm.search.trial import Trial
    from ipm.problem import POSE_NAMES, Problem
    from ipm.profiles import get_profile

    gen = get_generator("dishes")
    cam = UnknownCamera(pitch0=0.5, fov0=np.radians(50.0), fov_known=False, foot=(32.0, 60.0, 64, 64))
    problem = Problem(gen, np.array([0.0, 0.0, -3.0]), 1.0, camera=cam)
    z = problem.initial_z(gen.spec.to_unit(next(iter(gen.presets.values()))), 0.3)
    i, j = problem.n_shape + len(POSE_NAMES) + 2, problem.n_shape + len(POSE_NAMES)  # focal, pitch
    target = z[i] + 0.23
    held = []

    def objective(x, seed=None):  # lowest at the target focal length, with the pitch following it
        held.append(x[i])
        pitch = 0.9 + x[i] - target
        grad = np.zeros_like(x)
        grad[i], grad[j] = 2 * (x[i] - target), 2 * (x[j] - pitch)
        return float((x[i] - target) ** 2 + (x[j] - pitch) ** 2), grad

    profile = get_profile("smoke", focal_sweep=3, focal_step=0.1, focal_steps=40)
    out = sweep_focal(Trial(problem, objective, objective, lr=0.05, reject_ratio=1.2), z, profile.of(CameraSettings))
    assert out[i] == pytest.approx(z[i] + 0.2) and abs(out[j] - 0.87) < 0.5 * abs(z[j] - 0.87)
    grid = z[i] + 0.1 * np.arange(-3, 4)
    assert all(np.min(np.abs(grid - h)) < 1e-9 for h in held)  # the focal gene stayed on its grid points
    known = Problem(gen, np.array([0.0, 0.0, -3.0]), 1.0, camera=replace(cam, fov_known=True))
    assert MOVES["focal"].applies(problem, profile) and not MOVES["focal"].applies(known, profile)


def test_the_pitch_sweep_walks_the_pitch_after_the_focal_length():
    """With ``pitch_sweep`` the pitch is held on its own grid after the focal walk, and the lowest
    loss wins even where the gradient cannot move the pitch (a valley Adam does not cross)."""
    from ipm.generators import get_generator
    from ipm.search.moves import MOVES
    from ipm.search.moves.camera import CameraSettings, sweep_focal
    from ipm.search.trial import Trial
    from ipm.problem import POSE_NAMES, Problem
    from ipm.profiles import get_profile

    gen = get_generator("dishes")
    cam = UnknownCamera(pitch0=0.5, fov0=np.radians(50.0), fov_known=False, foot=(32.0, 60.0, 64, 64))
    problem = Problem(gen, np.array([0.0, 0.0, -3.0]), 1.0, camera=cam)
    z = problem.initial_z(gen.spec.to_unit(next(iter(gen.presets.values()))), 0.3)
    i, j = problem.n_shape + len(POSE_NAMES) + 2, problem.n_shape + len(POSE_NAMES)  # focal, pitch
    target, pitches = z[j] + np.radians(0.5), []

    def objective(x, seed=None):  # no gradient: only the grids move the camera
        pitches.append(x[j])
        return float((x[j] - target) ** 2 + (x[i] - z[i]) ** 2), np.zeros_like(x)

    settings = CameraSettings(focal_sweep=1, focal_steps=5, pitch_sweep=2, pitch_step=0.25)
    out = sweep_focal(Trial(problem, objective, objective, lr=0.05, reject_ratio=1.2), z, settings)
    assert out[i] == pytest.approx(z[i]) and out[j] == pytest.approx(target)
    grid = z[j] + np.radians(0.25) * np.arange(-2, 3)
    assert all(np.min(np.abs(grid - p)) < 1e-9 for p in pitches)


def test_auto_renders_an_unknown_field_of_view_with_mitsuba(tiny_case):
    """``renderer: auto`` keeps the camera-withheld path without a field of view on Mitsuba (its
    focal sweep was tuned with it; the JAX renderer is not validated there yet), and a known
    camera or field of view on the JAX renderer."""
    from ipm.generators import get_generator
    from ipm.search.objective import Objective
    from ipm.problem import Problem
    from ipm.profiles import get_profile
    from ipm.render.edges import EdgeRenderer
    from ipm.render.silhouette import SilhouetteRenderer

    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    photo = photo_views(tiny_case / frame["file_path"], tiny_case / frame["mask_path"], fov_deg=40.0)
    known = load_views(tiny_case / "transforms.json").first(1)
    gen, prof = get_generator("dishes"), get_profile("smoke", renderer="auto").objective
    assert isinstance(Objective(Problem.for_views(gen, photo), photo, 32, 0, prof).renderer, EdgeRenderer)
    bare = photo_views(tiny_case / frame["file_path"], tiny_case / frame["mask_path"])
    assert isinstance(Objective(Problem.for_views(gen, bare), bare, 32, 0, prof).renderer, SilhouetteRenderer)
    assert isinstance(Objective(Problem.for_views(gen, known), known, 32, 0, prof).renderer, EdgeRenderer)
    jax_photo = Objective(Problem.for_views(gen, bare), bare, 32, 0, get_profile("smoke", renderer="jax").objective)
    assert isinstance(jax_photo.renderer, EdgeRenderer)
