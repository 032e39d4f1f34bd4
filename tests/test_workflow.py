"""The Snakemake workflow: lint, dry run, and a smoke run of the whole DAG on tiny budgets."""
from __future__ import annotations

import json
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


@pytest.mark.parametrize("config", ["default", "smoke", "paper", "benchmark"])
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
    assert "results/reconstruct/diff_1v/cup_1/s0/mesh.ply" in out and "diff_1v/tree_1" not in out
    for gen in ("dishes", "trees"):
        assert out.count(f"output: results/prepare/ga/{gen}/s0.json") == 1
    assert "results/reconstruct/ga_1v/tree_1/s0/mesh.ply" in out and "results/reconstruct/ga_1v/cup_1/s0/mesh.ply" in out


def test_seeded_rows_run_per_seed_and_unseeded_ones_once(tmp_path):
    rc, out = dry_run(tmp_path, "cases: [cup_1, tree_1]\nseeds: [3, 4]\n"
                                "methods: [{name: ga, views: 1, cases: [tree_1]}, {name: visual_hull, views: 2},\n"
                                "          {name: diffsdf, views: 2, seeds: [5]}]\n")
    assert rc == 0, out
    for seed in (3, 4):  # the GA and its statistics once per seed
        assert f"results/reconstruct/ga_1v/tree_1/s{seed}/mesh.ply" in out
        assert out.count(f"output: results/prepare/ga/trees/s{seed}.json") == 1
    assert "visual_hull_2v/cup_1/s3/mesh.ply" in out and "visual_hull_2v/cup_1/s4/" not in out  # no random choices
    assert "diffsdf_2v/tree_1/s5/mesh.ply" in out and "diffsdf_2v/tree_1/s3/" not in out  # the row's own seeds
    assert "line_convex_hull/tree_1/s3/mesh.ply" in out and "line_convex_hull/tree_1/s4/" not in out


def test_device_cuda_declares_a_gpu_per_reconstruction(tmp_path):
    """``device: cuda`` reaches the reconstruct jobs, each declaring one GPU (so ``--resources
    gpu=N`` bounds how many run at once); the default runs them on the CPU without one."""
    rc, out = dry_run(tmp_path, "cases: [cup_1]\ndevice: cuda\nmethods: [{name: diff, views: 1}]\n")
    assert rc == 0, out
    job = out[out.index("rule reconstruct:"):]
    job = job[: job.index("\n\n")]
    assert "gpu=1" in job
    rc, out = dry_run(tmp_path, "cases: [cup_1]\nmethods: [{name: diff, views: 1}]\n")
    job = out[out.index("rule reconstruct:"):]
    assert "gpu=1" not in job[: job.index("\n\n")]
    rc, out = dry_run(tmp_path, "cases: [cup_1]\ndevice: tpu\n")
    assert rc != 0 and "tpu" in out


def test_tagged_entries_make_their_own_rows(tmp_path):
    """An ablation: the same method and view count twice, told apart by a tag (the GA with labels
    from the photo's colours and from the label images)."""
    rows = ("methods: [{name: ga, views: 1, settings: {labels: rgb}},\n"
            "          {name: ga, views: 1, tag: labelimages, settings: {labels: semantic}}]\n")
    rc, out = dry_run(tmp_path, "cases: [tree_1]\n" + rows)
    assert rc == 0, out
    assert "results/reconstruct/ga_1v/tree_1/s0/mesh.ply" in out
    assert "results/reconstruct/ga_1v_labelimages/tree_1/s0/mesh.ply" in out
    rc, out = dry_run(tmp_path, "cases: [tree_1]\nmethods: [{name: ga, views: 1}, {name: ga, views: 1}]\n")
    assert rc != 0 and "two methods entries make the row ga_1v; give one a tag" in out


@pytest.mark.slow
def test_smoke_run_of_the_whole_dag(tmp_path):
    res = snakemake("--cores", "2", "--configfile", str(ROOT / "pipelines/config/smoke.yaml"),
                    "--directory", str(tmp_path))
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    table = pd.read_csv(tmp_path / "results/table.csv")
    cases = {"cup_1", "cup_ext", "tree_1", "cup_t2", "cup_goblet", "building_1"}
    assert set(table["case"]) == cases
    assert set(table["label"]) == {"ours (diff, 1 view)", "ours (GA, 1 view)", "diffSDF-style (2 views)",
                                   "COLMAP known poses (16 views)", "visual hull (2 views)",
                                   "convex hull (reference)", "bounding sphere (reference)",
                                   "true parameters, other seed (reference)"}
    assert list(table["kind"].drop_duplicates()) == ["baseline", "method", "reference"]
    # diff: 3 cases x 2 seeds; GA, COLMAP: their cases; the reseeded truth: the one stochastic
    # in-family case (tree_1); the rest: every case, once
    assert len(table) == 6 + 2 + 1 + 1 + 4 * len(cases)
    assert set(table.loc[table["label"] == "true parameters, other seed (reference)", "case"]) == {"tree_1"}
    diff = table[table["label"] == "ours (diff, 1 view)"]
    assert set(diff["case"]) == {"cup_1", "cup_t2", "building_1"} and sorted(diff["seed"]) == [0, 0, 0, 1, 1, 1]
    assert set(table.loc[table["case"] == "cup_t2", "split"]) == {"test"}
    assert set(table.loc[table["case"] == "cup_1", "split"]) == {"dev"}
    assert set(table.loc[table["case"] == "cup_goblet", "family"]) == {"out"}
    # every row has metrics, or no metrics and the reason it failed (COLMAP on tiny images)
    failed = table["note"].fillna("").str.startswith("failed: ")
    assert (table.loc[failed, "label"] == "COLMAP known poses (16 views)").all()
    ok = table[~failed]
    assert ok["iou_mean"].between(0, 1).all() and ok["viou"].between(0, 1).all()
    assert (ok["shape_iou"] >= ok["iou_mean"] - 1e-9).all()  # alignment never lowers the IoU
    assert table.loc[failed, "iou_mean"].isna().all()
    # parameter recovery: in-family cases of the generator the row fits, nowhere else
    has_rec = ok["param_err"].notna()
    assert set(ok.loc[has_rec, "label"]) == {"ours (diff, 1 view)", "ours (GA, 1 view)"}
    assert (ok.loc[has_rec, "family"] == "in").all() and ok.loc[has_rec, "discrete_match"].between(0, 1).all()
    hull = table[table["label"] == "convex hull (reference)"]["iou_mean"]
    sphere = table[table["label"] == "bounding sphere (reference)"]["iou_mean"]
    assert (hull.values > sphere.values).all()  # the hull is the tighter reference line
    summary = pd.read_csv(tmp_path / "results/table_summary.csv")
    d = summary[(summary["label"] == "ours (diff, 1 view)") & (summary["case"] == "cup_1")].iloc[0]
    runs = diff.loc[diff["case"] == "cup_1", "iou_mean"]
    assert d["n_seeds"] == 2 and abs(d["iou_mean"] - runs.mean()) < 1e-4 and abs(d["iou_mean_worst"] - runs.min()) < 1e-4
    aggs = set(summary.loc[summary["label"] == "visual hull (2 views)", "case"]) - cases
    assert aggs == {"cups/dev/in", "cups/dev/out", "cups/dev/all", "cups/test/in", "cups/test/out", "cups/test/all",
                    "trees/dev/all", "buildings/dev/all"}
    md = (tmp_path / "results/table1.md").read_text()
    assert md.index("cups, test split") < md.index("cups, dev split")  # Table 1 is the test split
    html = (tmp_path / "results/report/index.html").read_text()
    assert "Table 1" in html and "ours (diff, 1 view)" in html and "data:image/png;base64" in html
    assert "test split" in html and "Parameter recovery" in html
    assert (tmp_path / "results/reconstruct/diff_1v/cup_1/s1/parts.png").is_file()
    assert (tmp_path / "results/synth/building_1/hemi1/semantic/000.png").is_file()  # window masks for the diff path
    assert json.loads((tmp_path / "results/reconstruct/diff_1v/building_1/s0/params.json").read_text())["generator"] == "buildings"
    assert (tmp_path / "results/reconstruct/ga_1v/tree_1/s0/parts.png").is_file()
    assert (tmp_path / "results/prepare/ga/trees/s0.json").is_file()
    assert (tmp_path / "logs/benchmark/reconstruct/diff_1v/cup_1/s0.tsv").is_file()
    wide = pd.read_csv(tmp_path / "results/table_iou.csv", index_col=0)
    assert list(wide.columns)[:5] == ["cup_1", "cup_ext", "tree_1", "cup_t2", "cup_goblet"]
    assert wide.loc["ours (diff, 1 view)", "tree_1"] != wide.loc["ours (diff, 1 view)", "tree_1"]  # NaN: "-"
    assert (tmp_path / "results/synth/cup_1/ring16/transforms.json").is_file()
