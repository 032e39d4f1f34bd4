"""The occupancy-network baseline: its frame, data, training, run, weights and command line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.occnet import PROFILES, OccnetSettings, fit, run_occnet
from baselines.occnet.data import LOCAL_BOX, make_occupancy_dataset, occupancy_points, to_local, to_world, view_frame
from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.learned.data import draw_sample
from ipm.methods import METHODS, resolve
from tests.conftest import as_the_package


@pytest.mark.parametrize("name", ["dishes", "buildings"])
def test_the_frame_maps_a_sample_to_the_local_box_and_back(name):
    """A training sample's own mesh, mapped to the frame its view fixes and back, is itself; there
    it stands on y = 0 inside the local box, about one unit high, with its camera on the +z side
    looking along -z (the frame turns the camera's azimuth onto +z exactly; where the camera
    stands across that axis is the anchor's offset from the line of sight, which a winged
    building's mask moves)."""
    gen = get_generator(name)
    for i in range(3):
        sample = draw_sample(gen, np.random.default_rng(200 + i))
        frame = view_frame(sample.mask, sample.c2w, sample.fov_x)
        local = to_local(sample.vertices, *frame)
        np.testing.assert_allclose(to_world(local, *frame), sample.vertices, atol=1e-9)
        assert local[:, 1].min() == pytest.approx(0.0, abs=1e-9) and 0.5 < local[:, 1].max() < 1.5
        assert (local >= LOCAL_BOX[0]).all() and (local <= LOCAL_BOX[1]).all()
        camera = to_local(sample.c2w[None, :3, 3], *frame)[0]
        back = to_local(sample.c2w[None, :3, 3] + sample.c2w[None, :3, 2], *frame)[0] - camera
        assert camera[2] > 0 and back[2] > 0 and abs(back[0]) < 1e-9 * np.linalg.norm(back)


def test_the_samples_are_the_regressors_and_overlapping_solids_stay_inside():
    """Same seed, same objects and network inputs as ``ipm.learned.data.make_dataset``; a point
    inside two overlapping closed boxes counts as inside (the volumetric metric's per-part test)."""
    import trimesh

    from ipm.learned.data import make_dataset

    gen = get_generator("buildings")
    ours, theirs = make_occupancy_dataset(gen, 3, seed=5, k=64), make_dataset(gen, 3, seed=5)
    np.testing.assert_array_equal(ours["image"], theirs["image"])
    np.testing.assert_array_equal(ours["cond"], theirs["cond"])
    assert ours["points"].shape == (3, 64, 3) and 0 < ours["occupied"].mean() < 1 and ours["outside"] == 0
    a, b = trimesh.creation.box((1, 1, 1)), trimesh.creation.box((1, 1, 1))
    b.apply_translation((0.5, 0, 0))
    both = trimesh.util.concatenate([a, b])
    points, inside = occupancy_points(both.vertices, both.faces, np.random.default_rng(0), 400,
                                      np.array([[-1.0, -1, -1], [1.5, 1, 1]]))
    expect = (points[:, 0] > -0.5) & (points[:, 0] < 1.0) & (np.abs(points[:, 1:]) < 0.5).all(1)
    overlap = (points[:, 0] > 0) & (points[:, 0] < 0.5) & (np.abs(points[:, 1:]) < 0.45).all(1)
    assert overlap.sum() > 5 and inside[overlap].all()
    assert np.mean(inside == expect) > 0.97  # exact but for points within rounding of a face


@pytest.fixture(scope="module")
def cup(tmp_path_factory, mitsuba_cpu):
    """cup_1 rendered at 64 px, one view."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("occnet") / "cup_1"
    synthesize("cup_1", out, n_views=1, res=64, spp=4, progress=False)
    return out


def test_the_catalogue_entry():
    """A baseline (tabled as one) that the workflow passes the case's generator and weights."""
    m = METHODS["occnet"]
    assert resolve(m.entry) is run_occnet and m.learns_generator and not m.uses_generator and m.prepare is not None
    assert m.takes_generator and m.layout == "hemi" and set(PROFILES) == {"smoke", "default", "paper"}
    assert not METHODS["ngp"].takes_generator and METHODS["diff"].takes_generator


@pytest.mark.slow
def test_the_smoke_run_trained_in_it(cup, tmp_path):
    """Without weights the run trains with the profile's budget; it writes a baseline's folder
    (about 12 s: slow)."""
    info = run_occnet(cup / "transforms.json", tmp_path / "a", generator="dishes", profile="smoke", progress=False)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["info.json", "mesh.ply", "timing.json"]
    saved = json.loads((tmp_path / "a" / "info.json").read_text())
    assert saved["weights"] == "trained in the run" and saved["training"]["samples"] == PROFILES["smoke"].samples
    assert 0 <= saved["training"]["held_out"]["accuracy"] <= 1
    assert saved["generator"] == "dishes" and saved["views"] == 1 and info["seconds"] > 0 and "failed" not in saved
    from ipm.io import load_mesh

    mesh = load_mesh(tmp_path / "a" / "mesh.ply")
    lo, hi = mesh.bounds
    assert len(mesh.faces) > 20 and lo[1] > -0.2 and hi[1] < 1.5  # near the cup (0.9 high, on y = 0)


def train_buildings(settings):
    """An occupancy network for the buildings trained with ``settings`` and seed 0, and its metadata."""
    return fit(get_generator("buildings"), settings, seed=0)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """An occupancy network for the buildings from a few hundred samples and steps, saved as the
    workflow's preparation stage saves it (the buildings: a few hundred steps learn their boxes,
    where the cups' walls, 0.03 thick, take the default budget's thousands)."""
    from baselines.occnet.network import save

    settings = OccnetSettings(samples=300, held_out=60, points=512, batch=16, batch_points=256, steps=400,
                              learning_rate=2e-3, mesh_grid=48)
    model, meta = as_the_package("tests.test_occnet:train_buildings", settings)  # as the preparation stage trains
    path = tmp_path_factory.mktemp("occnet_weights") / "buildings.json"
    save(model, path, meta)
    return model, meta, path


@pytest.fixture(scope="module")
def building(tmp_path_factory, mitsuba_cpu):
    """building_1 rendered at 64 px, one view (with its window labels)."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("occnet") / "building_1"
    synthesize("building_1", out, n_views=1, res=64, spp=4, progress=False)
    return out


@pytest.mark.slow
def test_held_out_occupancy_beats_the_constant_prediction(trained):
    _, meta, _ = trained
    held = meta["held_out"]  # measured: accuracy 0.82 against 0.68, IoU 0.60
    assert held["accuracy"] > held["constant_accuracy"] + 0.05 and held["iou"] > 0.4
    assert meta["samples"] == 300 and meta["held_out_samples"] == 60 and meta["in_channels"] == 2


@pytest.mark.slow
def test_a_prepared_network_reconstructs_the_building(trained, building, tmp_path):
    from ipm.io import load_mesh
    from ipm.metrics.evaluate import evaluate_meshes

    _, meta, path = trained
    info = run_occnet(building / "transforms.json", tmp_path / "b", generator="buildings", profile="smoke",
                      prepared=path, progress=False, mesh_grid=64)
    assert info["weights"] == "buildings.json" and "components_dropped" in info
    assert info["training"]["held_out"] == pytest.approx(meta["held_out"])
    mesh = load_mesh(tmp_path / "b" / "mesh.ply")
    assert mesh.is_watertight and len(mesh.faces) > 100
    scores = evaluate_meshes(load_mesh(building / "reference.ply"), mesh, n_views=8, res=64, grid=48)
    assert scores["iou_mean"] > 0.4


@pytest.mark.slow
def test_the_command_line_prepares_and_runs(trained, building, tmp_path, capsys):
    """``ipm prepare occnet`` writes weights with their held-out scores; ``ipm baseline occnet``
    runs with them."""
    from baselines.occnet.network import load
    from ipm.cli import main

    _, _, path = trained
    weights = tmp_path / "dishes.json"
    assert main(["prepare", "occnet", "--generator", "dishes", "--profile", "smoke", "--out", str(weights),
                 "--threads", "2", "--quiet"]) == 0
    _, meta = load(weights, "dishes")
    assert meta["in_channels"] == 1 and meta["samples"] == PROFILES["smoke"].samples and "accuracy" in meta["held_out"]
    assert main(["baseline", "occnet", "--generator", "buildings", "--prepared", str(path), "--views",
                 str(building / "transforms.json"), "--out", str(tmp_path / "c"), "--profile", "smoke",
                 "--threads", "2", "--quiet"]) == 0
    assert "mesh in" in capsys.readouterr().out and (tmp_path / "c" / "info.json").exists()


@pytest.mark.slow
def test_bad_weights_and_inputs_are_one_user_error_line(cup, tmp_path, capsys):
    import jax

    from baselines.occnet.network import OccupancyNet, load, save
    from ipm.cli import main

    path = tmp_path / "w.json"
    save(OccupancyNet(1, 64, 6, jax.random.PRNGKey(0)), path, {"generator": "dishes", "in_channels": 1, "res": 64,
                                                                "n_cond": 6})
    assert isinstance(load(path, "dishes")[0], OccupancyNet)
    with pytest.raises(UserError, match="not 'buildings'"):
        load(path, "buildings")
    record = json.loads(path.read_text())
    for name, text in [("a", "{not json"), ("b", json.dumps({"format": "other"})),
                       ("c", json.dumps({**record, "weights": record["weights"][:200]})),
                       ("d", json.dumps({**record, "hidden": 7}))]:
        (tmp_path / name).write_text(text)
        with pytest.raises(UserError, match="malformed|not an occupancy network|another network shape"):
            load(tmp_path / name)
    views = str(cup / "transforms.json")
    for args in (["baseline", "occnet", "--views", views, "--out", str(tmp_path / "x")],
                 ["baseline", "occnet", "--generator", "spoons", "--views", views, "--out", str(tmp_path / "x")],
                 ["baseline", "ngp", "--generator", "dishes", "--views", views, "--out", str(tmp_path / "x")],
                 ["baseline", "occnet", "--generator", "dishes", "--prepared", str(tmp_path / "a"), "--views", views,
                  "--out", str(tmp_path / "x")],
                 ["reconstruct", "--method", "occnet", "--generator", "dishes", "--views", views,
                  "--out", str(tmp_path / "x")]):
        assert main(args + ["--threads", "2", "--quiet"]) == 2, args
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and ": error:" in err, err
    assert "ipm baseline occnet --generator dishes" in err
    assert not (tmp_path / "x").exists()
    with pytest.raises(UserError, match="empty"):
        empty = tmp_path / "empty"
        _empty_mask_copy(cup, empty)
        run_occnet(empty / "transforms.json", tmp_path / "y", generator="dishes", profile="smoke", prepared=path)


def _empty_mask_copy(case, out):
    """A copy of a one-view case whose mask is all background."""
    import shutil

    from PIL import Image

    shutil.copytree(case, out)
    frame = json.loads((out / "transforms.json").read_text())["frames"][0]
    mask = out / frame["mask_path"]
    Image.fromarray(np.zeros_like(np.asarray(Image.open(mask)))).save(mask)
