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
from tests.conftest import as_the_package, slow_except


def _views(sample) -> Views:
    return Views(fov_x=sample.fov_x, width=sample.mask.shape[1], height=sample.mask.shape[0],
                 c2w=sample.c2w[None], masks=sample.mask[None])


def test_training_seeds_are_disjoint_from_every_case():
    """No case's sampler seed falls in the training range, so no test object is trained on."""
    from ipm.cases import SAMPLED, list_cases, load_case

    seeds = {s for _, _, s, _, _ in SAMPLED}
    seeds |= {load_case(c).get("sampler", {}).get("seed", 0) for c in list_cases()}
    assert max(seeds) < TRAIN_SEED_BASE


@pytest.mark.parametrize("name", slow_except(["dishes", "buildings"], "dishes"))
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


def test_a_photo_proposal_is_the_known_camera_one_at_the_render_camera():
    """With the camera genes at the render camera's, an unknown camera's problem places a proposal
    exactly where a known camera there would: the camera-hidden proposals share the known ones' map."""
    from ipm.learned.propose import start_z
    from ipm.photo import at_proposed_camera, c2w, unknown_camera_views

    gen = get_generator("dishes")
    mask = np.zeros((64, 64), np.float32)
    mask[30:56, 24:40] = 1
    pitch, fov = np.radians(25.0), np.radians(45.0)
    known = Views(fov_x=fov, width=64, height=64, c2w=c2w(pitch)[None], masks=mask[None])
    photo = at_proposed_camera(unknown_camera_views(known, fov_known=False), pitch, fov)
    assert photo.camera.pitch0 == pytest.approx(pitch) and photo.fov_x == pytest.approx(fov)
    a, b = Problem.for_views(gen, known), Problem.for_views(gen, photo)
    u, pose = gen.spec.to_unit(gen.presets["mug"]), np.array([0.05, -0.1, 0.2])
    za, zb = start_z(a, u, 0.3, pose, known.c2w[0]), start_z(b, u, 0.3, pose, photo.c2w[0])
    assert len(zb) == len(za) + 3
    np.testing.assert_allclose(a.world_mesh(za, 1).vertices, b.world_mesh(zb, 1).vertices, atol=1e-5)
    given_fov = at_proposed_camera(unknown_camera_views(known, fov_known=True), pitch, 1.2)
    assert given_fov.fov_x == pytest.approx(fov)  # a field of view the photo came with is kept


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
    """A regressor for the cups trained on a small set (it must beat the mean prediction on
    held-out samples), saved as the workflow saves it."""
    from ipm.learned.network import save
    from ipm.learned.train import TrainSettings

    # 1,000 steps: at 500 the discrete accuracy sat at the most frequent values' (0.475 against
    # 0.492 on one AVX-512 CPU, above it on another); at 1,000 it is 0.62 against 0.49
    settings = TrainSettings(samples=480, held_out=120, steps=1000, batch=32, learning_rate=2e-3)
    model, meta = as_the_package("tests.test_learned:train_cups", settings)  # as the preparation stage trains
    path = tmp_path_factory.mktemp("learned") / "dishes.json"
    save(model, path, meta)
    return model, meta, path


def train_cups(settings):
    """A regressor for the cups trained with ``settings`` and seed 0, and its metadata."""
    from ipm.learned.train import fit

    return fit(get_generator("dishes"), settings, seed=0)


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


@pytest.fixture(scope="module")
def cup_view(tmp_path_factory, mitsuba_cpu):
    """cup_1's input view, small."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("cup")
    synthesize("cup_1", out, n_views=1, res=64, spp=4, progress=False)
    return out / "transforms.json"


@pytest.mark.slow
def test_the_camera_hidden_variant_proposes_the_camera_of_a_photo(cup_view, tmp_path):
    """Trained with the camera hidden, the regressor's pitch beats the mean prediction's on held-out
    samples; its row withholds the view's camera, proposes one and is placed to be scored."""
    from ipm.learned.network import save
    from ipm.learned.propose import load_regressor
    from ipm.learned.train import TrainSettings, fit
    from ipm.io import load_views
    from ipm.methods.learned import run_learned_photo
    from ipm.photo import at_proposed_camera, withheld
    from ipm.profiles import get_profile
    from ipm.search.moves.camera import PitchStarts

    settings = TrainSettings(samples=240, held_out=60, steps=200, batch=32, learning_rate=2e-3)
    model, meta = fit(get_generator("dishes"), settings, seed=0, camera_hidden=True)
    assert meta["camera_hidden"] and len(meta["pose_mean"]) == 5
    assert meta["held_out"]["pitch_error_deg"] < meta["mean_prediction"]["pitch_error_deg"]
    path = tmp_path / "dishes_photo.json"
    save(model, path, meta)
    info = run_learned_photo(cup_view, tmp_path / "out", generator="dishes", profile="smoke", prepared=path,
                             progress=False)
    assert info["method"] == "learned_photo" and info["weights"] == "dishes_photo.json"
    assert set(info["camera_error"]) == {"pitch_deg", "roll_deg", "fov_rel"} and info["camera"]["roll_deg"] == 0.0
    assert (tmp_path / "out" / "mesh.ply").is_file()
    with pytest.raises(UserError, match="holds the camera-hidden regressor, not the known-camera one"):
        load_regressor("dishes", path)
    # the camera-withheld diff path from a proposed camera (run with the shipped weights in
    # tests/test_photo.py): no pitch starts there, as with a field of view given they run
    problem = Problem.for_views(get_generator("dishes"), at_proposed_camera(withheld(load_views(cup_view)), 0.3, 0.8))
    assert not PitchStarts().applies(problem, get_profile("default"))
    assert PitchStarts().applies(Problem.for_views(get_generator("dishes"), withheld(load_views(cup_view), True)),
                                 get_profile("default"))


@pytest.mark.slow
def test_the_learned_row_and_start(trained, cup_view, tmp_path):
    """The learned row writes a reconstruction like any other; the learned start puts its proposals
    first in the memetic population."""
    from ipm.io import load_views
    from ipm.learned.propose import discrete_choices, propose
    from ipm.methods.learned import run_learned
    from ipm.optim.memetic import MemeticSettings
    from ipm.learned.propose import has_weights
    from ipm.photo import unknown_camera_views
    from ipm.search.starts import learned_start, preset_start, start_for

    _, _, path = trained
    info = run_learned(cup_view, tmp_path / "out", generator="dishes", profile="smoke", prepared=path, progress=False)
    assert {"mesh.ply", "mesh.glb", "params.json", "timing.json"} <= {p.name for p in (tmp_path / "out").iterdir()}
    assert info["method"] == "learned" and info["generator"] == "dishes"
    views = load_views(cup_view)
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


def test_the_memetic_stage_is_shorter_from_the_learned_start(tiny_case, monkeypatch):
    """From a learned start the memetic stage runs ``learned_generations`` generations (at most the
    profile's ``ga_iterations``); from the presets all of them."""
    from ipm.io import load_views
    from ipm.profiles import get_profile
    from ipm.search import loop
    from ipm.search.starts import preset_start

    class Stop(Exception):
        pass

    seen = []

    def memetic(pop, objective, clip, key_of, n_shape, levels, settings, *rest, **kw):
        seen.append(settings.ga_iterations)
        raise Stop

    def plain(problem, settings, rng, prepare=None):
        return preset_start(problem, settings, rng)

    def learned(problem, settings, rng, prepare=None):
        return preset_start(problem, settings, rng)

    learned.learned = True
    monkeypatch.setattr(loop, "memetic", memetic)
    views = load_views(tiny_case / "transforms.json").subset([0])
    problem = Problem.for_views(get_generator("dishes"), views)
    for profile, start in [(get_profile("default", ga_iterations=12), learned),
                           (get_profile("default", ga_iterations=12, learned_generations=6), learned),
                           (get_profile("default", ga_iterations=12), plain), (get_profile("smoke"), learned)]:
        with pytest.raises(Stop):
            loop.reconstruct(problem, views, profile, progress=False, start=start)
    assert seen == [4, 6, 12, 2]


@pytest.mark.slow
def test_a_learned_start_that_fits_badly_adds_the_presets_stage(tiny_case, monkeypatch):
    """``learned_fit``: where the best loss of the memetic stage from the learned start is above it,
    the stage runs again from the presets' start at full length, both last generations reach the
    finalists, and the trace's ``start`` rows (params.json's ``start``) say what the check saw and
    which stage the best came from; ``None`` or a loose threshold keep the learned stage alone."""
    import pandas as pd

    from ipm.io import load_views
    from ipm.methods.diff import start_record
    from ipm.profiles import get_profile
    from ipm.search import loop
    from ipm.search.starts import preset_start
    from ipm.search.trial import TRACE_COLUMNS

    class Stop(Exception):
        pass

    calls, made, seen = [], [], {}

    def memetic(pop, objective, clip, key_of, n_shape, levels, settings, *rest, **kw):
        calls.append((settings.ga_iterations, {ind.origin for ind in pop}))
        worse = 0.05 if len(calls) == 1 else 0.0  # the learned stage fits worse than the presets'
        for k, ind in enumerate(pop):
            ind.best_loss, ind.best_z = 0.1 + 0.01 * k + worse, ind.z
        return sorted(pop, key=lambda ind: ind.best_loss)

    def finalists(problem, final, k):
        seen["final"] = final
        raise Stop

    def learned(problem, settings, rng, prepare=None):
        pop = preset_start(problem, settings, rng)
        pop[0].origin = "learned"
        return pop

    learned.learned = True

    class Kept(loop.Tracker):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(loop, "memetic", memetic)
    monkeypatch.setattr(loop, "finalists", finalists)
    monkeypatch.setattr(loop, "Tracker", Kept)
    views = load_views(tiny_case / "transforms.json").subset([0])
    problem = Problem.for_views(get_generator("dishes"), views)
    for fit, stages in ((0.0, 2), (None, 1), (1.0, 1)):
        calls.clear()
        profile = get_profile("default", ga_iterations=12, learned_fit=fit)
        with pytest.raises(Stop):
            loop.reconstruct(problem, views, profile, progress=False, start=learned)
        trace = pd.DataFrame(made[-1].rows, columns=TRACE_COLUMNS)
        start = trace[trace["stage"] == "start"]
        record = start_record(trace, profile)["start"]
        assert [n for n, _ in calls] == [4, 12][:stages] and "learned" in calls[0][1]
        assert record["learned_fit"] == fit and record["checks"] == [{"loss": pytest.approx(0.15), "presets_added": stages == 2}]
        if stages == 2:
            assert "learned" not in calls[1][1] and len(seen["final"]) == 2 * profile.memetic.population
            assert list(start["origin"]) == ["learned: presets added", "won: presets"]
            assert record["won"] == "presets" and seen["final"][0].best_loss == pytest.approx(0.1)
        else:
            assert list(start["origin"]) == ["learned: kept"] and record["won"] == "learned"


def test_choices_apart_proposes_each_other_plan_once():
    """``choices_apart``: for every value of the named discrete parameters but the given one, the most
    probable joint with it, most probable first."""
    from ipm.learned.propose import choices_apart

    probs = [np.array([0.7, 0.1, 0.15, 0.05]), np.array([0.4, 0.6]), np.array([0.2, 0.8])]
    out = choices_apart(probs, ["template", "annex", "roof"], {"template": 0})
    assert [c for c, _ in out] == [(2, 1, 1), (1, 1, 1), (3, 1, 1)]
    assert [p for _, p in out] == pytest.approx([0.15 * 0.6 * 0.8, 0.1 * 0.6 * 0.8, 0.05 * 0.6 * 0.8])
    both = choices_apart(probs, ["template", "annex", "roof"], {"template": 1, "annex": 1})
    assert len(both) == 7 and (1, 1, 1) not in [c for c, _ in both]


@pytest.fixture(scope="module")
def building_view(tmp_path_factory, mitsuba_cpu):
    """building_1 rendered at 64 px, one view."""
    from tests.conftest import synthesized

    return synthesized(tmp_path_factory, "building_1", n_views=1, res=64, spp=4) / "transforms.json"


@pytest.mark.slow
def test_a_poor_plan_adds_a_finalist_from_the_other_plans(building_view, tiny_case, monkeypatch):
    """``plan_check``: where the input-view IoU of the learned stage's best is below it, a stage as
    long runs from the regressor's joint for each other plan (``start.elsewhere``: shipped weights,
    every plan but the best's once) and its best basin joins the learned stage's finalists as one
    more; the trace's ``start`` rows (params.json's ``start``) say what the check saw. At or above
    it, with ``None``, or for a generator without plan parameters (the dishes), the finalists are
    the learned stage's alone. A ``z`` checked is ray-cast once."""
    import pandas as pd

    from ipm.io import load_views
    from ipm.methods.diff import start_record
    from ipm.optim.memetic import MemeticSettings
    from ipm.profiles import get_profile
    from ipm.search import loop
    from ipm.search.starts import learned_start
    from ipm.search.trial import TRACE_COLUMNS

    views = load_views(building_view)
    problem = Problem.for_views(get_generator("buildings"), views)
    start = learned_start(views)
    best = start(problem, MemeticSettings(population=6), np.random.default_rng(0))[0].z
    others = start.elsewhere(problem, MemeticSettings(population=6), np.random.default_rng(0), lambda z: z, best)
    plan = problem.spec.index["template"]
    plans = [int(round(problem.spec.from_unit(ind.z[: problem.n_shape])[plan])) for ind in others[:3]]
    first = int(round(problem.spec.from_unit(best[: problem.n_shape])[plan]))
    assert [ind.origin for ind in others[:3]] == ["other plan"] * 3 and len(others) == 6
    assert sorted(plans + [first]) == [0, 1, 2, 3] and others[3].origin != "other plan"

    class Stop(Exception):
        pass

    calls, made, chosen = [], [], []
    real_finalists = loop.finalists

    def memetic(pop, objective, clip, key_of, n_shape, levels, settings, *rest, **kw):
        calls.append({ind.origin for ind in pop})
        for k, ind in enumerate(pop):
            ind.best_loss, ind.best_z = 0.1 + 0.01 * k, ind.z
        return sorted(pop, key=lambda ind: ind.best_loss)

    def finalists(problem, final, k):
        out = real_finalists(problem, final, k)
        chosen[:] = [ind.origin for ind in out]
        return out

    class Stopped(loop.Tracker):  # stops the fit once its finalists are chosen
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

        def enter(self, stage, res, reset=False):
            if stage != "memetic":
                raise Stop
            super().enter(stage, res, reset)

    monkeypatch.setattr(loop, "memetic", memetic)
    monkeypatch.setattr(loop, "finalists", finalists)
    monkeypatch.setattr(loop, "Tracker", Stopped)
    cast = []
    monkeypatch.setattr(loop, "input_iou", lambda *a, **k: cast.append(1) or 0.9)
    cup_views = load_views(tiny_case / "transforms.json").subset([0])
    cup = Problem.for_views(get_generator("dishes"), cup_views)
    for prob, check, stages in ((problem, 0.95, 2), (problem, 0.9, 1), (problem, None, 1), (cup, 0.95, 1)):
        calls.clear(), cast.clear()
        profile = get_profile("default", population=6, plan_check=check)
        with pytest.raises(Stop):
            loop.reconstruct(prob, views if prob is problem else cup_views, profile, progress=False, start=start)
        trace = pd.DataFrame(made[-1].rows, columns=TRACE_COLUMNS)
        origins = list(trace[trace["stage"] == "start"]["origin"])
        record = start_record(trace, profile)["start"]
        assert len(calls) == stages and "learned" in calls[0] and record["plan_check"] == check
        n = profile.loop.refine_candidates
        assert len(cast) == 1  # the check's best is the finalists' first: its view is cast once
        if stages == 2:  # the learned stage's finalists, then the other plans' best
            assert "other plan" in calls[1] and "learned" not in calls[1]
            assert chosen[-1] == "other plan" and "other plan" not in chosen[:-1] and len(chosen) == n + 1
            assert origins[1:] == ["plan check: input IoU 0.9000, other plans added"]
            assert record["plan_checks"] == [{"input_iou": 0.9, "other_plans_added": True}]
        else:
            assert "other plan" not in chosen and len(chosen) == n
            if check is not None and prob is problem:
                assert origins[1:] == ["plan check: input IoU 0.9000, plan kept"]
            else:
                assert not record["plan_checks"]
