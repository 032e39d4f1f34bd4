"""The Snakemake workflow: lint, dry run, and a smoke run of the whole DAG on tiny budgets."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def snakemake(*args, cwd=ROOT, timeout=900):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run([*SNAKEMAKE, "--snakefile", str(ROOT / "Snakefile"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_lint_is_clean():
    res = snakemake("--lint", "--cores", "1")
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Congratulations" in res.stdout + res.stderr


@pytest.mark.parametrize("config", ["default", "smoke", "paper"])
def test_dry_run_plans_every_stage(config, tmp_path):
    res = snakemake("-n", "--cores", "2", "--configfile", str(ROOT / f"pipelines/config/{config}.yaml"),
                    "--directory", str(tmp_path))
    assert res.returncode == 0, res.stdout + res.stderr
    for rule in ("reference", "synth", "reconstruct", "reference_line", "evaluate", "parts_preview", "table", "report"):
        assert f"rule {rule}:" in res.stdout


def dry_run(tmp_path, config_text: str):
    """A dry run with the config ``config_text``: (exit code, stdout + stderr)."""
    cfg = tmp_path / "config.yaml"
    cfg.write_text(config_text)
    res = snakemake("-n", "--cores", "1", "--configfile", str(cfg), "--directory", str(tmp_path))
    return res.returncode, res.stdout + res.stderr


def test_invalid_config_is_refused(tmp_path):
    rc, out = dry_run(tmp_path, "profile: turbo\n")
    assert rc != 0 and "turbo" in out


def test_unknown_method_is_refused(tmp_path):
    rc, out = dry_run(tmp_path, "methods: [{name: nerf, views: 16}]\n")
    assert rc != 0 and "unknown method 'nerf'" in out


def test_diff_on_a_tree_case_is_refused(tmp_path):
    rc, out = dry_run(tmp_path, "cases: [cup_1, tree_1]\nmethods: [{name: diff, views: 1}]\n")
    assert rc != 0 and "case tree_1: method 'diff' needs a differentiable generator" in out
    rc, out = dry_run(tmp_path, "cases: [cup_1]\nmethods: [{name: ga, views: 1, cases: [tree_1]}]\n")
    assert rc != 0 and "lists case 'tree_1', which is not in cases" in out


def test_rows_run_on_their_cases_and_the_ga_statistics_once_per_generator(tmp_path):
    rc, out = dry_run(tmp_path, "cases: [cup_1, tree_1]\n"
                                "methods: [{name: diff, views: 1, cases: [cup_1]}, {name: ga, views: 1}]\n")
    assert rc == 0, out
    assert "results/reconstruct/diff_1v/cup_1/mesh.ply" in out and "diff_1v/tree_1" not in out
    for gen in ("dishes", "trees"):
        assert out.count(f"output: results/prepare/ga/{gen}.json") == 1
    assert "results/reconstruct/ga_1v/tree_1/mesh.ply" in out and "results/reconstruct/ga_1v/cup_1/mesh.ply" in out


@pytest.mark.slow
def test_smoke_run_of_the_whole_dag(tmp_path):
    res = snakemake("--cores", "2", "--configfile", str(ROOT / "pipelines/config/smoke.yaml"),
                    "--directory", str(tmp_path))
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    table = pd.read_csv(tmp_path / "results/table.csv")
    assert set(table["case"]) == {"cup_1", "cup_ext", "tree_1"}
    assert set(table["label"]) == {"ours (diff, 1 view)", "ours (GA, 1 view)", "diffSDF-style (2 views)",
                                   "COLMAP known poses (16 views)", "visual hull (2 views)",
                                   "convex hull (reference)", "bounding sphere (reference)"}
    assert list(table["kind"].drop_duplicates()) == ["baseline", "method", "reference"]
    assert len(table) == 3 * 7 - 1  # the diff path skips the tree
    assert set(table.loc[table["label"] == "ours (diff, 1 view)", "case"]) == {"cup_1", "cup_ext"}
    # every row has metrics, or no metrics and the reason it failed (COLMAP on tiny images)
    failed = table["note"].fillna("").str.startswith("failed: ")
    assert (table.loc[failed, "label"] == "COLMAP known poses (16 views)").all()
    ok = table[~failed]
    assert ok["iou_mean"].between(0, 1).all() and ok["viou"].between(0, 1).all()
    assert table.loc[failed, "iou_mean"].isna().all()
    hull = table[table["label"] == "convex hull (reference)"]["iou_mean"]
    sphere = table[table["label"] == "bounding sphere (reference)"]["iou_mean"]
    assert (hull.values > sphere.values).all()  # the hull is the tighter reference line
    html = (tmp_path / "results/report/index.html").read_text()
    assert "Table 1" in html and "ours (diff, 1 view)" in html and "data:image/png;base64" in html
    assert (tmp_path / "results/reconstruct/diff_1v/cup_1/parts.png").is_file()
    assert (tmp_path / "results/reconstruct/ga_1v/tree_1/parts.png").is_file()
    assert (tmp_path / "results/prepare/ga/trees.json").is_file()
    wide = pd.read_csv(tmp_path / "results/table_iou.csv", index_col=0)
    assert list(wide.columns) == ["cup_1", "cup_ext", "tree_1"]
    assert wide.loc["ours (diff, 1 view)", "tree_1"] != wide.loc["ours (diff, 1 view)", "tree_1"]  # NaN: "-"
    assert (tmp_path / "results/synth/cup_1/ring16/transforms.json").is_file()
