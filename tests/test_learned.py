"""The learned proposals: training data, the regressor, its proposals as starts and as a row."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.io.views import Views
from ipm.learned.data import (TRAIN_SEED_BASE, crop_box, draw_sample, encode_view, make_dataset, sample_lod,
                              targets)
from ipm.problem import Problem


def _views(sample) -> Views:
    return Views(fov_x=sample.fov_x, width=sample.mask.shape[1], height=sample.mask.shape[0],
                 c2w=sample.c2w[None], masks=sample.mask[None])


def test_training_seeds_are_disjoint_from_every_case():
    """No case's sampler seed falls in the training range, so no test object is trained on."""
    from ipm.cases import SAMPLED
    from ipm.synth import list_cases, load_case

    seeds = {s for _, _, s, _, _ in SAMPLED}
    seeds |= {load_case(c).get("sampler", {}).get("seed", 0) for c in list_cases()}
    assert max(seeds) < TRAIN_SEED_BASE


@pytest.mark.parametrize("name", ["dishes", "buildings"])
def test_targets_rebuild_the_sample_exactly(name):
    """The targets in the search's coordinates, turned back into a problem's z by the proposal's
    own map, give the sample's mesh: the conventions of pose, anchor and camera frame agree."""
    from ipm.learned.propose import start_z

    gen = get_generator(name)
    for i in range(3):
        sample = draw_sample(gen, np.random.default_rng(100 + i))
        t = targets(gen, sample)
        problem = Problem.for_views(gen, _views(sample))
        z = start_z(problem, gen.spec.to_unit(gen.spec.clip(sample.x)), float(np.arctan2(t["yaw"][1], t["yaw"][0])),
                    t["pose"], sample.c2w)
        mesh = problem.world_mesh(z, sample_lod(gen))
        np.testing.assert_allclose(mesh.vertices, sample.vertices, atol=1e-5)


def test_class_masks_lie_inside_the_silhouette():
    gen = get_generator("buildings")
    sample = draw_sample(gen, np.random.default_rng(3))
    assert sample.class_mask is not None and sample.class_mask.sum() > 0
    assert np.all(sample.class_mask <= sample.mask)


def test_the_input_is_the_crop_wherever_the_object_sits():
    """The image is the square crop around the mask: a shifted mask gives the same image, and the
    camera numbers say where the crop was."""
    mask = np.zeros((96, 96), np.float32)
    mask[30:60, 20:40] = 1
    shifted = np.roll(mask, (10, 25), (0, 1))
    c2w = np.eye(4)
    a, ca = encode_view(mask, c2w, 0.7)
    b, cb = encode_view(shifted, c2w, 0.7)
    np.testing.assert_allclose(a, b)
    assert cb[2] > ca[2] and cb[3] > ca[3] and cb[4] == pytest.approx(ca[4])
    assert 0.3 < a.mean() < 0.6
    with pytest.raises(ValueError, match="empty"):
        crop_box(np.zeros((8, 8)))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A regressor for the cups trained on a small set (the issue's check: it must beat the mean
    prediction on held-out samples), saved as the workflow saves it."""
    from ipm.learned.network import save
    from ipm.learned.train import TrainSettings, fit

    gen = get_generator("dishes")
    settings = TrainSettings(samples=480, held_out=120, steps=500, batch=32, learning_rate=2e-3)
    model, meta = fit(gen, settings, seed=0)
    path = tmp_path_factory.mktemp("learned") / "dishes.json"
    save(model, path, meta)
    return model, meta, path


@pytest.mark.slow
def test_the_regressor_beats_the_mean_prediction_on_held_out_samples(trained):
    _, meta, _ = trained
    net, mean = meta["held_out"], meta["mean_prediction"]
    assert net["param_mae"] < mean["param_mae"]
    assert net["pose_mae"][2] < mean["pose_mae"][2]  # the object's height over the anchor's
    assert net["discrete_accuracy"] >= mean["discrete_accuracy"]
    assert net["yaw_error_deg"] < 90.0


@pytest.mark.slow
def test_weights_round_trip_and_bad_files_fail_clearly(trained, tmp_path):
    from ipm.learned.network import load
    from ipm.learned.train import predict

    model, meta, path = trained
    again, meta2 = load(path, expect_generator="dishes")
    data = make_dataset(get_generator("dishes"), 4, seed=7)
    a, b = predict(model, data["image"], data["cond"]), predict(again, data["image"], data["cond"])
    np.testing.assert_allclose(a["u"], b["u"], atol=2e-3)  # stored as float16
    assert meta2["levels"] == meta["levels"]
    with pytest.raises(UserError, match="not 'buildings'"):
        load(path, expect_generator="buildings")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(UserError, match="malformed"):
        load(bad)
    bad.write_text(json.dumps({"format": "other"}))
    with pytest.raises(UserError, match="not a learned regressor"):
        load(bad)
    with pytest.raises(UserError, match="no learned weights"):
        load(tmp_path / "missing.json")


@pytest.mark.slow
def test_the_learned_row_and_start(trained, tmp_path, mitsuba_cpu):
    """The learned row writes a reconstruction like any other; the learned start puts its proposals
    first in the memetic population."""
    from ipm.io import load_views
    from ipm.learned.propose import discrete_choices, propose
    from ipm.methods.learned import run_learned
    from ipm.optim.memetic import MemeticSettings
    from ipm.learned.propose import has_weights
    from ipm.photo import unknown_camera_views
    from ipm.search.starts import learned_start, preset_start, start_for
    from ipm.synth import synthesize

    _, _, path = trained
    synthesize("cup_1", tmp_path / "cup", n_views=1, res=64, spp=4, progress=False)
    info = run_learned(tmp_path / "cup" / "transforms.json", tmp_path / "out", generator="dishes",
                       profile="smoke", prepared=path, progress=False)
    assert {"mesh.ply", "mesh.glb", "params.json", "timing.json"} <= {p.name for p in (tmp_path / "out").iterdir()}
    assert info["method"] == "learned" and info["generator"] == "dishes"
    views = load_views(tmp_path / "cup" / "transforms.json")
    problem = Problem.for_views(get_generator("dishes"), views)
    zs = propose(problem, views, k=2, prepared=path)
    assert len(zs) == 2 and all(np.all(np.isfinite(z)) for z in zs)
    assert problem.key(zs[0]) != problem.key(zs[1])  # the two handle choices
    pop = learned_start(views, 2, path)(problem, MemeticSettings(population=6), np.random.default_rng(0))
    assert [ind.origin for ind in pop[:2]] == ["learned", "learned"] and len(pop) == 6
    # the default start is the learned one where it applies, the presets where it does not
    assert start_for(problem, views, "learned", 2, path) is not preset_start
    assert start_for(problem, views, "presets", 2, path) is preset_start
    photo = unknown_camera_views(views, fov_known=False)
    assert start_for(Problem.for_views(get_generator("dishes"), photo), photo, "learned", 2, path) is preset_start
    assert not has_weights("trees") and has_weights("dishes") and has_weights("trees", path)
    choices = discrete_choices([np.array([0.1, 0.9]), np.array([0.6, 0.3, 0.1])], 3)
    assert [c for c, _ in choices] == [(1, 0), (1, 1), (1, 2)]
