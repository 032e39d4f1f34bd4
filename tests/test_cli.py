"""The command line: bad input gives one clear line and a non-zero exit, and no output directory."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest


def ipm(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "ipm.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


def _one_line_error(res):
    assert res.returncode != 0
    lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    return lines[0]


@pytest.mark.slow
def test_unknown_generator(tmp_path, tiny_case):
    out = tmp_path / "out"
    res = ipm("reconstruct", "--generator", "teapot", "--views", str(tiny_case / "transforms.json"),
              "--out", str(out), "--profile", "smoke")
    assert "unknown generator 'teapot'" in _one_line_error(res)
    assert not out.exists()


@pytest.mark.parametrize("problem", ["missing", "malformed", "nan", "bad_profile", "wrong_size"])
def test_bad_reconstruct_input(tmp_path, tiny_case, problem):
    views = tmp_path / "transforms.json"
    data = json.loads((tiny_case / "transforms.json").read_text())
    for fr in data["frames"]:
        fr["mask_path"] = str(tiny_case / fr["mask_path"])
    profile = "smoke"
    if problem == "malformed":
        views.write_text("{")
    elif problem == "nan":
        data["frames"][0]["transform_matrix"][0][0] = float("nan")
        views.write_text(json.dumps(data))
    elif problem == "wrong_size":
        data["w"] = 80
        views.write_text(json.dumps(data))
    elif problem == "bad_profile":
        views.write_text(json.dumps(data))
        profile = "turbo"
    out = tmp_path / "out"
    res = ipm("reconstruct", "--generator", "dishes", "--views", str(views), "--out", str(out), "--profile", profile)
    line = _one_line_error(res)
    assert line.startswith("ipm reconstruct: error:")
    assert not out.exists()


def test_evaluate_errors(tmp_path, tiny_case):
    res = ipm("evaluate", "--reference", str(tmp_path / "none.ply"), "--mesh", str(tiny_case / "reference.ply"),
              "--out", str(tmp_path / "m.json"))
    assert "mesh file not found" in _one_line_error(res)
    assert not (tmp_path / "m.json").exists()


def test_unknown_case(tmp_path):
    res = ipm("synth", "--case", "nope", "--out", str(tmp_path / "s"))
    assert "unknown case 'nope'" in _one_line_error(res)
    assert not (tmp_path / "s").exists()


@pytest.mark.slow
def test_evaluate_and_reference_line_commands(tmp_path, tiny_case):
    ref = str(tiny_case / "reference.ply")
    assert ipm("reference-line", "convex_hull", "--reference", ref, "--out", str(tmp_path / "hull")).returncode == 0
    res = ipm("evaluate", "--reference", ref, "--mesh", str(tmp_path / "hull" / "mesh.ply"),
              "--out", str(tmp_path / "m.json"), "--views", "16", "--res", "64", "--grid", "32")
    assert res.returncode == 0, res.stderr
    m = json.loads((tmp_path / "m.json").read_text())
    assert 0.8 < m["iou_mean"] < 1.0 and m["viou"] < 1.0  # the hull fills the cup and its handle hole


@pytest.mark.slow
def test_methods_refuse_generators_and_stages_they_cannot_use(tmp_path, tiny_case):
    views = str(tiny_case / "transforms.json")
    res = ipm("reconstruct", "--method", "diff", "--generator", "trees", "--views", views, "--out", str(tmp_path / "r"))
    assert "needs a differentiable generator; 'trees'" in _one_line_error(res)
    res = ipm("reconstruct", "--method", "diffsdf", "--generator", "dishes", "--views", views, "--out", str(tmp_path / "r"))
    assert "is a baseline" in _one_line_error(res)
    for method in ("diff", "photo"):  # the weights of their learned starts
        res = ipm("reconstruct", "--method", method, "--generator", "dishes", "--views", views, "--out",
                  str(tmp_path / "r"), "--prepared", str(tmp_path / "x.json"))
        assert "--prepared: no such file" in _one_line_error(res)
    res = ipm("reconstruct", "--method", "ga", "--generator", "dishes", "--views", views, "--out", str(tmp_path / "r"),
              "--max-tilt", "0.1")
    assert "--max-tilt applies to the diff path only" in _one_line_error(res)
    res = ipm("reconstruct", "--generator", "dishes", "--views", views, "--out", str(tmp_path / "r"), "--max-tilt", "nan")
    assert "diff setting max_tilt must be a finite number, got nan" in _one_line_error(res)
    res = ipm("reconstruct", "--generator", "dishes", "--views", views, "--out", str(tmp_path / "r"), "--max-tilt", "0.6")
    assert "diff setting max_tilt must be >= 0 and <= 0.5, got 0.6" in _one_line_error(res)
    res = ipm("reconstruct", "--generator", "dishes", "--views", views, "--out", str(tmp_path / "r"),
              "--window-weight", "-1")
    assert "diff setting window_weight must be >= 0 and <= 100, got -1.0" in _one_line_error(res)
    res = ipm("reconstruct", "--method", "ga", "--generator", "dishes", "--views", views, "--out", str(tmp_path / "r"),
              "--renderer", "jax")
    assert "--renderer applies to the diff path only" in _one_line_error(res)
    res = ipm("prepare", "diff", "--generator", "dishes", "--out", str(tmp_path / "p.json"))
    assert "no preparation stage" in _one_line_error(res)
    res = ipm("prepare", "ga", "--generator", "teapot", "--out", str(tmp_path / "p.json"))
    assert "unknown generator 'teapot'" in _one_line_error(res)
    assert not (tmp_path / "r").exists() and not (tmp_path / "p.json").exists()


@pytest.mark.slow
def test_prepare_writes_statistics_the_ga_reads(tmp_path):
    from ipm.optim.ga_statistics import GeneStatistics

    out = tmp_path / "stats" / "trees.json"
    res = ipm("prepare", "ga", "--generator", "trees", "--profile", "smoke", "--out", str(out), "--quiet",
              "--threads", "1")
    assert res.returncode == 0, res.stderr
    stats = GeneStatistics.load(out)
    assert stats.n_samples == 24 and stats.names[-1] == "pose_scale"
    assert [p.name for p in out.parent.iterdir()] == ["trees.json"]  # nothing half-written beside it


@pytest.mark.slow
def test_cases_lists_every_case_with_its_split():
    res = ipm("cases", "--split", "test")
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()[1:]
    assert all(" test " in ln for ln in lines) and any(ln.startswith("cup_goblet") for ln in lines)
    assert any("sampled" in ln and ln.startswith("tree_t1") for ln in lines)
    assert any(ln.startswith("cup_t5") and ln.endswith("63.8 deg") for ln in lines)  # its own lens
    assert any(ln.startswith("cup_t1") and ln.endswith("39.6 deg") for ln in lines)
    res = ipm("cases")
    assert res.returncode == 0 and any(ln.startswith("cup_1 ") and " dev " in ln for ln in res.stdout.splitlines())
    from ipm.cases import list_cases

    # the whole listing reaches the pipe, to its last case, though the command ends without teardown
    assert [ln.split()[0] for ln in res.stdout.strip().splitlines()[1:]] == list_cases()
