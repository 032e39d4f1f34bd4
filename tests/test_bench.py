"""The benchmark scripts' own arithmetic (their timings live in docs/results.md, not here)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_devices_agree_compares_images_losses_and_gradients():
    """Identical numbers agree exactly; a changed pixel, loss and gradient show as such."""
    compare = _script("devices_agree").compare
    rng = np.random.default_rng(0)
    there = {"jax/64/image": rng.random((1, 8, 8)).astype(np.float32), "jax/64/loss": np.float64(0.5),
             "jax/64/grad": rng.normal(size=5)}
    (same,) = compare(dict(there), there)
    assert same == {"renderer": "jax", "width": 64, "pixels": 64, "pixels_differ": 0, "max_coverage_diff": 0.0,
                    "loss_rel_diff": 0.0, "grad_rel_diff": 0.0}
    here = {k: np.array(v, copy=True) for k, v in there.items()}
    here["jax/64/image"][0, 2, 3] += 0.75
    here["jax/64/image"][0, 4, 4] += 0.25  # an edge pixel's coverage, not a different pixel
    here["jax/64/loss"] = np.float64(0.55)
    here["jax/64/grad"] = 1.1 * there["jax/64/grad"]
    (row,) = compare(here, there)
    assert row["pixels_differ"] == 1 and np.isclose(row["max_coverage_diff"], 0.75)
    assert np.isclose(row["loss_rel_diff"], 0.1) and np.isclose(row["grad_rel_diff"], 0.1)


def test_cup_fits_splits_a_trace_into_steady_time_and_events():
    """Gaps over the threshold are events (a stage's first call), the rest steady evaluations."""
    import pandas as pd

    split_time = _script("cup_fits").split_time
    trace = pd.DataFrame({"stage": ["memetic"] * 4 + ["refine"] * 3,
                          "seconds": np.cumsum([2.0, 0.003, 0.004, 0.003, 1.5, 0.004, 0.005])})
    row = split_time(trace, 0.05)
    assert row["events"] == 2 and row["seconds_events"] == 3.5
    assert row["seconds_steady"] == 0.02 and row["median_eval_ms"] == 4.0 and row["memetic_s"] == 2.01


def test_warm_fit_splits_a_trace_into_its_stages_in_order():
    """Each run of one stage and width is a stage, a stage met again later a new one; the gap
    before a stage's first row is the stage's."""
    import pandas as pd

    stage_seconds = _script("warm_fit").stage_seconds
    trace = pd.DataFrame({"stage": ["memetic"] * 3 + ["refine"] * 2 + ["refine"] + ["memetic"],
                          "res": [96, 96, 96, 128, 128, 256, 96],
                          "seconds": [1.0, 1.5, 2.0, 3.0, 3.5, 5.0, 5.25]})
    assert stage_seconds(trace) == [{"stage": "memetic", "res": 96, "evaluations": 3, "seconds": 2.0},
                                    {"stage": "refine", "res": 128, "evaluations": 2, "seconds": 1.5},
                                    {"stage": "refine", "res": 256, "evaluations": 1, "seconds": 1.5},
                                    {"stage": "memetic", "res": 96, "evaluations": 1, "seconds": 0.25}]
    assert _script("warm_fit").merged(stage_seconds(trace)) == [
        {"stage": "memetic", "res": "96", "evaluations": 3, "seconds": 2.0},
        {"stage": "refine", "res": "128/256", "evaluations": 3, "seconds": 3.0},
        {"stage": "memetic", "res": "96", "evaluations": 1, "seconds": 0.25}]


def test_mask_robustness_degrades_the_input_mask_and_measures_against_the_true_masks_fit(tmp_path):
    """The copied views folder holds the degraded mask (its IoU with the true one returned), nothing
    else changes; losses are against the same case and seed's fit to the true mask."""
    import json

    from PIL import Image

    bench = _script("mask_robustness")
    src = tmp_path / "views"
    (src / "masks").mkdir(parents=True)
    y, x = np.mgrid[:64, :64]
    mask = (x - 32) ** 2 + (y - 32) ** 2 <= 15**2
    Image.fromarray((mask * 255).astype(np.uint8)).save(src / "masks/000.png")
    (src / "transforms.json").write_text(json.dumps({"frames": [{"mask_path": "masks/000.png"}]}))
    dst, iou = bench.degraded_views(src, tmp_path / "out", "edge -2 px", 0)
    out = np.asarray(Image.open(dst / "masks/000.png")) > 127
    assert (out <= mask).all() and out.sum() < mask.sum()
    assert abs(iou - out.sum() / mask.sum()) <= 5e-5  # recorded to 4 places
    assert (np.asarray(Image.open(src / "masks/000.png")) > 127).sum() == mask.sum()  # the source untouched
    rows = bench.with_losses([{"case": "c", "seed": 0, "degradation": "none", "shape_iou": 0.9, "world_iou": 0.8},
                              {"case": "c", "seed": 0, "degradation": "hole", "shape_iou": 0.85, "world_iou": 0.82}])
    assert [(r["shape_loss"], r["world_loss"]) for r in rows] == [(0.0, 0.0), (0.05, -0.02)]


def test_segmentation_scores_masks_and_groups_them_by_class_family_and_backdrop():
    """IoU of a mask with the truth, and the summary's means and worst per group."""
    seg = _script("segmentation")
    truth = np.zeros((4, 4), bool)
    truth[:2] = True
    half = np.zeros((4, 4))
    half[0] = 1.0
    assert seg.score(half, truth) == 0.5 and seg.score(truth.astype(float), truth) == 1.0
    rows = [{"case": "a", "backdrop": "table", "class": "cups", "family": "in", "colour": 0.5, "learned": 0.9},
            {"case": "a", "backdrop": "floor", "class": "cups", "family": "in", "colour": 0.7, "learned": 0.8},
            {"case": "b", "backdrop": "table", "class": "buildings", "family": "out", "colour": 0.9, "learned": 1.0}]
    out = seg.summary(rows, ["colour", "learned"])
    assert out["all"]["colour"] == {"mean": 0.7, "worst": 0.5, "n": 3}
    assert out["cups in"]["learned"] == {"mean": 0.85, "worst": 0.8, "n": 2}
    assert out["table"]["learned"]["mean"] == 0.95 and out["buildings out"]["colour"]["n"] == 1


def test_texture_paints_ground_truths_of_the_generators_only_and_tables_them(tmp_path):
    """The truth row is refused for a case a generator did not make (its charts have no symmetry to
    fill by); the table gives it a line of its own beside ours' fit."""
    from ipm.errors import UserError

    bench = _script("texture")
    with pytest.raises(UserError, match="not made by a generator"):
        bench.truth("cup_ext", tmp_path, 1)
    side = {"psnr": 20.0, "ssim": 0.5}
    rows = [{"case": "cup_1", "row": r, "inputs": 1, "refine": "default", "sides": {"input": side, "seen": side}}
            for r in ("diff", "truth")]
    lines = bench.table(rows).splitlines()
    assert len(lines) == 4 and lines[3].startswith("| cup_1 | truth | 1 | - | 20.0 / 0.500 | 20.0 / 0.500 | - |")


def test_compile_profile_adds_up_processes_by_program_and_test():
    """Totals over processes (with the seconds spent compiling a program, by its cache key, again);
    programs ranked by compile seconds with their cache hits; tests by compile, trace and lowering
    seconds (a record outside a test goes to "-")."""
    prof = _script("compile_profile")
    worker = {"cpu_s": 10.0, "records": [["miss", "t::a", "jit_fn", 0.0], ["compile", "t::a", "jit_fn", 3.0],
                                         ["trace", "t::a", None, 0.5], ["hit", "t::b", "jit_fn", 0.0],
                                         ["read", "t::b", None, 0.1], ["lower", "t::b", None, 0.25]]}
    job = {"cpu_s": 4.0, "records": [["miss", "-", "jit_inline", 0.0],
                                     ["compile", "-", "jit_inline", 1.0, "(f32[4])", "jit_inline-k1"],
                                     ["compile", "t::a", "jit_fn", 2.0],
                                     ["compile", "-", "jit_inline", 0.5, "(f32[4])", "jit_inline-k1"],
                                     ["compile", "-", "jit_inline", 0.5, "(f32[8])"], ["compile", "-", None, 0.5, "()"],
                                     ["compile", "-", None, 0.5, "()"]]}
    out = prof.summarize([worker, job], top=5)
    assert out["processes"] == 2
    assert out["totals"] == {"cpu_s": 14.0, "compile_s": 8.0, "trace_s": 0.5, "lower_s": 0.25, "read_s": 0.1,
                             "hits": 1, "misses": 2, "same_program_again_s": 0.75}  # k1 twice: one of 0.75 s
    assert out["programs"] == [{"program": "jit_fn", "compiles": 2, "seconds": 5.0, "hits": 1},
                               {"program": "jit_inline", "compiles": 3, "seconds": 2.0, "hits": 0},
                               {"program": "?", "compiles": 2, "seconds": 1.0, "hits": 0}]
    # the same shapes compiled twice (a budget baked in); records without shapes or a name are left out
    assert out["same_shapes"] == [{"program": "jit_inline", "shapes": "(f32[4])", "compiles": 2, "seconds": 1.5}]
    assert out["tests"] == [{"test": "t::a", "seconds": 5.5}, {"test": "-", "seconds": 3.0},
                            {"test": "t::b", "seconds": 0.25}]
    assert "| jit_fn | 2 | 5.0 | 1 |" in prof.markdown(out) and "| jit_inline (f32[4]) | 2 | 1.5 |" in prof.markdown(out)


@pytest.mark.slow
def test_compile_profile_records_a_process_it_starts(tmp_path, monkeypatch):
    """The hook in a real process: a jitted program's compile is recorded under its name, with the
    test running at the time, and the process's CPU time."""
    import json
    import sys

    code = ("import ipm.runtime as r; r.configure_threads(1); import jax, jax.numpy as jnp\n"
            "def sine_gram(x):\n    return jnp.sin(x) @ x.T\n"
            "jax.jit(sine_gram)(jnp.ones((64, 64))).block_until_ready()")
    monkeypatch.setenv("IPM_JAX_CACHE", str(tmp_path / "cache"))
    out, kept = tmp_path / "out.json", tmp_path / "records"
    rc = _script("compile_profile").main(["--out", str(out), "--keep", str(kept), "--", sys.executable, "-c", code])
    summary = json.loads(out.read_text())
    assert rc == 0 and summary["processes"] == 1 and summary["totals"]["cpu_s"] > 0, summary
    records = json.loads(next(kept.glob("*.json")).read_text())["records"]  # kept: with each compile's cache key
    keys = [r[5] for r in records if r[0] == "compile" and r[2] == "jit_sine_gram"]
    assert len(keys) == 1 and keys[0].startswith("jit_sine_gram-"), records
    assert summary["totals"]["misses"] >= 1 and summary["totals"]["compile_s"] > 0, summary
    assert any(p["program"] == "jit_sine_gram" and p["compiles"] == 1 for p in summary["programs"]), summary
    assert all(r["program"] != "jit_sine_gram" for r in summary["same_shapes"]), summary  # one compile
    assert summary["tests"][0]["test"].startswith("tests/test_bench.py::test_compile_profile_records"), summary


def test_paired_compares_a_tagged_row_with_its_twin_by_case_and_seed(tmp_path, capsys):
    """Each tagged row meets its untagged twin on the same case and seed: the paired mean and SE,
    each class and family's means, the worst case; a run without a twin is left out and counted;
    bad input is one line and exit 2."""
    import json

    import pandas as pd

    paired = _script("paired")
    rows = []
    for case, gen, fam, base, cand in [("cup_1", "dishes", "in", (0.90, 0.92), (0.91, 0.92)),
                                       ("cup_ext", "dishes", "out", (0.80, 0.70), (0.80, 0.60)),
                                       ("building_1", "buildings", "in", (0.95, 0.85), (0.96, 0.86))]:
        for seed in (0, 1):
            rows.append({"row": "diff_1v", "case": case, "generator": gen, "family": fam, "seed": seed,
                         "iou_mean": base[seed]})
            rows.append({"row": "diff_1v_prior", "case": case, "generator": gen, "family": fam, "seed": seed,
                         "iou_mean": cand[seed]})
    rows.append({"row": "diff_1v_prior", "case": "cup_2", "generator": "dishes", "family": "in", "seed": 0,
                 "iou_mean": 0.5})
    rows.append({"row": "diff_1v_maskedgep2px", "case": "cup_1", "generator": "dishes", "family": "in", "seed": 0,
                 "iou_mean": 0.5})
    table = pd.DataFrame(rows)
    assert paired.twins(list(table["row"].drop_duplicates())) == [("diff_1v", "diff_1v_prior")]
    r = paired.compare(table, "diff_1v", "diff_1v_prior")
    changes = np.array([0.01, 0.0, 0.0, -0.1, 0.01, 0.01])
    assert r["metric"] == "iou_mean" and r["pairs"] == 6 and r["left_out"] == 1 and r["moved"] == 4
    assert r["paired"] == pytest.approx(changes.mean(), abs=1e-4)
    assert r["se"] == pytest.approx(changes.std(ddof=1) / np.sqrt(6), abs=1e-4)
    assert r["groups"]["cups out"] == {"cases": 1, "base": 0.75, "cand": 0.7}
    assert r["groups"]["buildings in"]["cand"] == pytest.approx(0.91)
    assert r["worst_case"] == {"case": "cup_ext", "change": -0.05}
    path = tmp_path / "table.csv"
    table.to_csv(path, index=False)
    assert paired.main([str(path), "--out", str(tmp_path / "p.json")]) == 0
    assert "diff_1v_prior against diff_1v on iou_mean: paired -0.0117" in capsys.readouterr().out
    assert json.loads((tmp_path / "p.json").read_text())[0]["pairs"] == 6
    assert paired.main([str(tmp_path / "none.csv")]) == 2
    assert paired.main([str(path), "--pair", "diff_1v", "ngp_16v"]) == 2
    assert paired.main([str(path), "--metric", "nope"]) == 2
    assert paired.main([str(path), "--pair", "diff_1v", "diff_1v_maskedgep2px"]) == 0  # one pair: no SE
    table.assign(case=table["case"].where(table["row"] != "diff_1v_maskedgep2px", "cup_9")).to_csv(path, index=False)
    assert paired.main([str(path), "--pair", "diff_1v", "diff_1v_maskedgep2px"]) == 2
    err = capsys.readouterr().err
    assert "no rows ngp_16v" in err and "share no case and seed" in err


def test_plan_alternatives_lay_every_plan_over_the_fit_s_extent(rng):
    """Each plan laid over a building's footprint, moved by the offset it returns, covers the same
    extent, and its wings are switched on as the plan and the annex say."""
    from ipm.generators import get_generator

    bench = _script("plan_alternatives")
    gen = get_generator("buildings")
    for _ in range(5):
        p = gen.spec.as_dict(gen.sample(rng))
        x0, x1, z0, z1 = bench.extent(p)
        for plan in range(4):
            for annex in (0, 1):
                q, move = bench.laid(p, plan, annex)
                assert (q["template"], q["annex"]) == (plan, annex) and move[1] == 0.0
                n0, n1, m0, m1 = bench.extent(q)
                np.testing.assert_allclose([n0 + move[0], n1 + move[0], m0 + move[2], m1 + move[2]], [x0, x1, z0, z1],
                                           atol=1e-12)
                assert n1 - n0 == pytest.approx(x1 - x0) and m1 - m0 == pytest.approx(z1 - z0)


@pytest.mark.slow
def test_plan_alternatives_start_the_truth_where_the_synthesis_put_it(mitsuba_cpu, tmp_path_factory, tmp_path):
    """``--truth``: a synthesised building's parameters and pose as a search vector decode back to
    themselves; a case made without a generator's parameters is one clear error."""
    import json

    from ipm.generators import get_generator
    from ipm.io.views import load_views
    from ipm.problem import Problem
    from tests.conftest import synthesized

    bench = _script("plan_alternatives")
    case = synthesized(tmp_path_factory, "building_1", n_views=1, res=32, spp=1)
    gen = get_generator("buildings")
    problem = Problem.for_views(gen, load_views(case / "transforms.json"))
    truth = bench.truth_fit(case)
    back = problem.decode(problem.clip(bench.fitted_z(problem, truth)))
    np.testing.assert_allclose(gen.spec.from_dict(back["params"]), gen.spec.from_dict(truth["params"]), atol=1e-9)
    pose, want = back["pose"], json.loads((case / "ground_truth.json").read_text())["pose"]
    assert np.degrees(pose["yaw"]) == pytest.approx(want["yaw_deg"]) and pose["tilt_x"] == pose["tilt_z"] == 0.0
    np.testing.assert_allclose(pose["translation"], want["translation"], atol=1e-9)
    assert pose["scale"] == pytest.approx(want["scale"])
    (tmp_path / "ground_truth.json").write_text(json.dumps({"source": {"recipe": "independent code"}, "pose": want}))
    with pytest.raises(SystemExit, match="no generator parameters"):
        bench.truth_fit(tmp_path)
