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

from tests.conftest import slow_except

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


@pytest.mark.parametrize("config", slow_except(["default", "smoke", "paper", "benchmark"], "smoke"))
def test_dry_run_plans_every_stage(config, tmp_path):
    # the benchmark config (17 000 jobs, a minute of planning) on a test case of each class: its
    # rows, settings and every case name are still checked, every row and rule planned
    narrow = ["--config", "cases=[cup_t1, building_t1, tree_t1]"] if config == "benchmark" else []
    res = snakemake("-n", "--cores", "2", "--configfile", str(ROOT / f"pipelines/config/{config}.yaml"),
                    "--directory", str(tmp_path), *narrow)
    assert res.returncode == 0, res.stdout + res.stderr
    for rule in ("reference", "synth", "reconstruct", "reference_line", "evaluate", "parts_preview", "table", "report",
                 "report_check"):
        assert f"rule {rule}:" in res.stdout
    # the trainings and the GA's statistics: made in the run, but read from the shipped files by default
    assert ("rule prepare:" in res.stdout) == (config != "default")
    # ours' textures scored where the config names colour views for them (not the paper's)
    assert ("rule texture:" in res.stdout) == ("rule texture_table:" in res.stdout) == (config != "paper")


def dry_run(tmp_path, config_text: str):
    """A dry run with the config ``config_text``: (exit code, stdout + stderr)."""
    cfg = tmp_path / "config.yaml"
    cfg.write_text(config_text)
    res = snakemake("-n", "--cores", "1", "--configfile", str(cfg), "--directory", str(tmp_path))
    return res.returncode, res.stdout + res.stderr


@pytest.mark.slow
def test_invalid_config_is_refused(tmp_path):
    rc, out = dry_run(tmp_path, "profile: turbo\n")
    assert rc != 0 and "turbo" in out


@pytest.mark.slow
def test_unknown_method_is_refused(tmp_path):
    rc, out = dry_run(tmp_path, "methods: [{name: nerf, views: 16}]\n")
    assert rc != 0 and "unknown method 'nerf'" in out


@pytest.mark.slow
def test_diff_on_a_tree_case_is_refused(tmp_path):
    rc, out = dry_run(tmp_path, "cases: [cup_1, tree_1]\nmethods: [{name: diff, views: 1}]\n")
    assert rc != 0 and "case tree_1: method 'diff' needs a differentiable generator" in out
    rc, out = dry_run(tmp_path, "cases: [cup_1]\nmethods: [{name: ga, views: 1, cases: [tree_9]}]\n")
    assert rc != 0 and "tree_9" in out  # an unknown case in a row's list is refused
    rc, out = dry_run(tmp_path, "cases: [cup_1, tree_1]\nmethods: [{name: ga, views: 1, cases: [tree_1], "
                                "seeds: {cup_1: [0, 1]}}]\n")
    assert rc != 0 and "seeds for cup_1, a case it does not run on" in out


@pytest.mark.slow
def test_config_cases_narrow_every_row(tmp_path):
    """``--config 'cases=[cup_goblet]'`` on the default config runs just that case, though the rows
    keep their own case lists (they are intersected with ``cases``)."""
    res = snakemake("-n", "--cores", "1", "--configfile", str(ROOT / "pipelines/config/default.yaml"),
                    "--directory", str(tmp_path), "--config", "cases=[cup_goblet]")
    out = res.stdout + res.stderr
    assert res.returncode == 0, out
    runs = {line.split("results/reconstruct/")[1].split("/")[1] for line in out.splitlines()
            if "output: results/reconstruct/" in line}
    assert runs == {"cup_goblet"}
    for row in ("diff_1v", "learned_1v", "occnet_1v", "diffsdf_6v", "ngp_16v", "colmap_sfm_16v", "visual_hull_6v",
                "line_convex_hull"):
        assert f"results/reconstruct/{row}/cup_goblet/s0" in out
    assert "ga_1v" not in out  # the GA row lists only trees


@pytest.mark.slow
def test_other_seeds_of_a_compiling_method_wait_for_the_first(tmp_path):
    """The diff path's second seed of a case runs after its first (it reads the programs the first
    compiled) and the GA's beside it (nothing to share); a rerun of the first seed alone is not a
    reason to rerun the second (``ancient``). A row's seeds may be given per case."""
    rc, out = dry_run(tmp_path, "profile: smoke\nprepare_seed: 0\ncases: [cup_1, tree_1]\nseeds: [0]\n"
                                "methods: [{name: diff, views: 1, cases: [cup_1], seeds: {cup_1: [0, 1]}}, "
                                "{name: ga, views: 1, cases: [tree_1], seeds: [0, 1]}]\n")
    assert rc == 0, out[-3000:]
    jobs = {}  # each reconstruction's output -> its inputs
    for block in out.split("rule reconstruct:\n")[1:]:
        fields = dict(line.strip().split(": ", 1) for line in block.splitlines()[:2])
        jobs[fields["output"]] = fields["input"].split(", ")
    run = "results/reconstruct/{}/s{}".format
    assert run("diff_1v/cup_1", 0) in jobs[run("diff_1v/cup_1", 1)]
    assert run("diff_1v/cup_1", 1) not in jobs[run("diff_1v/cup_1", 0)]
    assert run("ga_1v/tree_1", 0) not in jobs[run("ga_1v/tree_1", 1)] and len(jobs) == 4
    from ipm.methods import METHODS

    assert METHODS["diff"].compiles and not METHODS["ga"].compiles


@pytest.mark.slow
def test_a_mask_row_reads_its_views_with_degraded_masks(tmp_path):
    """A methods entry with a ``mask`` reads a copy of its views whose masks a ``degrade_masks``
    job degraded, under its own row id; an unknown degradation is refused when the DAG is built."""
    rc, out = dry_run(tmp_path, "profile: smoke\ncases: [cup_1]\nmask_seed: 4\nmethods: [{name: diff, views: 1}, "
                                "{name: diff, views: 1, mask: 'edge +2 px'}]\n")
    assert rc == 0, out[-3000:]
    job = out[out.index("rule degrade_masks:"):]
    assert "input: results/synth/cup_1/hemi1\n" in job and "output: results/synth/cup_1/hemi1_maskedgep2px" in job
    runs = {}
    for block in out.split("rule reconstruct:\n")[1:]:
        fields = dict(line.strip().split(": ", 1) for line in block.splitlines()[:2])
        runs[fields["output"]] = fields["input"]
    assert runs["results/reconstruct/diff_1v_maskedgep2px/cup_1/s0"].startswith("results/synth/cup_1/hemi1_maskedgep2px")
    assert runs["results/reconstruct/diff_1v/cup_1/s0"].startswith("results/synth/cup_1/hemi1,")
    rc, out = dry_run(tmp_path, "profile: smoke\ncases: [cup_1]\nmethods: [{name: diff, views: 1, mask: blur}]\n")
    assert rc != 0 and "unknown mask degradation 'blur'" in out


@pytest.mark.slow
def test_the_default_config_reads_the_shipped_preparations(tmp_path):
    """The default run trains nothing: its learned rows, the diff path's learned start and the GA
    read the files the package ships (the same weights on every machine; the other configs make
    them in the run, ``test_dry_run_plans_every_stage``); ``prepared: shipped`` with another
    profile's budgets is refused."""
    from ipm.methods import METHODS

    res = snakemake("-n", "--cores", "1", "--configfile", str(ROOT / "pipelines/config/default.yaml"),
                    "--directory", str(tmp_path))
    out = res.stdout + res.stderr
    assert res.returncode == 0, out[-3000:]
    assert "rule prepare:" not in out
    for stage, generator in (("learned", "dishes"), ("learned", "buildings"), ("occnet", "dishes"),
                             ("occnet", "buildings"), ("ga", "trees")):
        assert str(METHODS[stage].shipped_file(generator)) in out, (stage, generator)
    rc, out = dry_run(tmp_path, "profile: smoke\nprepared: shipped\ncases: [cup_1]\n")
    assert rc != 0 and "prepared: shipped are the default profile's preparations" in out


@pytest.mark.parametrize("profile", ["slurm", "kubernetes"])
@pytest.mark.slow
def test_cluster_profiles_dry_run(profile, tmp_path):
    """The executor profiles plan the default DAG: SLURM on a shared filesystem, Kubernetes with
    every file going through the storage provider; reconstructions ask for a GPU with cuda."""
    res = snakemake("-n", "--profile", str(ROOT / "profiles" / profile), "--configfile",
                    str(ROOT / "pipelines/config/default.yaml"), "--directory", str(tmp_path), "--config", "device=cuda")
    out = res.stdout + res.stderr
    assert res.returncode == 0, out[-3000:]
    job = out[out.index("rule reconstruct:"):]
    job = job[: job.index("\n\n")]
    assert "gpu=1" in job and "runtime=60" in job and "mem_mb=4000" in job
    if profile == "kubernetes":
        assert "(send to storage)" in job and "gpu_manufacturer=nvidia" in job
    else:
        assert "cpus_per_task=1" in job and "(send to storage)" not in job


def test_config_readme_names_every_key():
    """pipelines/config/README.md documents every key of the config schema."""
    import yaml

    schema = yaml.safe_load((ROOT / "pipelines/schemas/config.schema.yaml").read_text())
    doc = (ROOT / "pipelines/config/README.md").read_text()
    keys = list(schema["properties"])
    keys += [f"methods[].{k}" for k in schema["properties"]["methods"]["items"]["properties"]]
    for section in ("synth", "evaluate"):
        keys += list(schema["properties"][section]["properties"])
    missing = [k for k in keys if f"`{k}`" not in doc]
    assert not missing, f"undocumented config keys: {missing}"


def test_workflow_is_snakefmt_clean():
    files = [ROOT / "Snakefile", *sorted((ROOT / "pipelines/rules").glob("*.smk"))]
    res = subprocess.run([sys.executable, "-m", "snakefmt", "--check", *map(str, files)], capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stdout + res.stderr


STORAGE = ("--default-storage-provider", "fs", "--shared-fs-usage", "none")
"""Run jobs as on a cluster without a shared working directory: every input comes from the storage
(here a folder) into a local copy and only declared outputs go back, so a file a job writes beside
its outputs without declaring it stays behind in the local copies (and never reaches a job on
another machine that would read it)."""


def undeclared(workdir: Path) -> list[str]:
    """What a storage run left behind other than logs and Snakemake's own files: files written
    beside declared outputs (in the local storage copies) or into the working directory."""
    local = workdir / ".snakemake" / "storage"
    out = [str(p.relative_to(local)) for p in local.rglob("*") if p.is_file() and "/logs/" not in str(p)]
    return sorted(out + [p.name for p in workdir.iterdir() if p.name != ".snakemake"])


@pytest.mark.slow
def test_storage_run_catches_undeclared_files(tmp_path):
    """The check the smoke run relies on: a rule that writes a file beside its output without
    declaring it leaves it behind, where :func:`undeclared` finds it; declared files do not."""
    (tmp_path / "Snakefile").write_text(
        'rule all:\n    input: "r/b.txt"\n\n'
        'rule a:\n    output: "r/a.txt"\n    log: "logs/a.log"\n'
        '    shell: "echo a > {output}; echo x > $(dirname {output})/extra.txt"\n\n'
        'rule b:\n    input: "r/a.txt"\n    output: "r/b.txt"\n    shell: "cat {input} > {output}"\n')
    args = ["--snakefile", str(tmp_path / "Snakefile"), "--cores", "1", "--directory", str(tmp_path / "work"),
            *STORAGE, "--default-storage-prefix", str(tmp_path / "store")]
    res = subprocess.run([*SNAKEMAKE, *args], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert (tmp_path / "store/r/b.txt").is_file() and not (tmp_path / "store/r/extra.txt").exists()
    left = undeclared(tmp_path / "work")
    assert len(left) == 1 and left[0].endswith("/r/extra.txt"), left


@pytest.mark.slow
def test_smoke_run_of_the_whole_dag(tmp_path):
    """The whole DAG on the smoke config, run as on a cluster without a shared working directory
    (:data:`STORAGE`): every job finds the files it declared and leaves nothing undeclared behind;
    then the report's browser check and ``snakemake --report``."""
    work, store = tmp_path / "work", tmp_path / "store"
    args = ("--configfile", str(ROOT / "pipelines/config/smoke.yaml"), "--directory", str(work), *STORAGE,
            "--default-storage-prefix", str(store))
    res = snakemake("--cores", "2", *args, timeout=1800)  # 7.5 minutes on this project's slower machine
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    assert undeclared(work) == []
    res = snakemake("--report", str(tmp_path / "report.zip"), *args)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    import zipfile

    names = zipfile.ZipFile(tmp_path / "report.zip").namelist()
    assert any(n.endswith("/table.csv") for n in names) and any(n.endswith("/index.html") for n in names)
    check = json.loads((store / "results/report/screenshots/check.json").read_text())
    assert check["screenshots"] and all((store / "results/report/screenshots" / n).is_file()
                                        for n in check["screenshots"])
    tmp_path = store  # the results as the storage holds them
    table = pd.read_csv(tmp_path / "results/table.csv")
    cases = {"cup_1", "tree_1", "cup_goblet", "building_1"}
    assert set(table["case"]) == cases
    masked = "ours (diff, 1 view) [mask: edge +4 px]"  # 1 px at the smoke run's 64 px
    assert set(table["label"]) == {"ours (diff, 1 view)", masked, "ours (GA, 1 view)", "diffSDF-style (2 views)",
                                   "learned regressor (1 view)",
                                   "COLMAP known poses (16 views)", "visual hull (2 views)",
                                   "convex hull (reference)", "true parameters, other seed (reference)"}
    assert list(table["kind"].drop_duplicates()) == ["baseline", "method", "reference"]
    # diff: the cup's 2 seeds and the building's 1, on a degraded mask 1; the learned row, GA, COLMAP, diffSDF, the visual
    # hull: their cases; the reseeded truth: the one stochastic in-family case (tree_1); the convex
    # hull: every case, once
    assert len(table) == 3 + 1 + 1 + 2 + 1 + 2 + 1 + 1 + len(cases)
    assert table.loc[table["label"] == masked, "mask"].tolist() == ["edge +4 px"]
    degraded = json.loads((store / "results/synth/cup_1/hemi1_maskedgep4px/degradation.json").read_text())
    assert degraded["degradation"] == "edge +4 px" and 0.5 < degraded["mask_iou"][0] < 1.0
    assert set(table.loc[table["label"] == "diffSDF-style (2 views)", "case"]) == {"cup_1", "building_1"}
    assert set(table.loc[table["label"] == "true parameters, other seed (reference)", "case"]) == {"tree_1"}
    diff = table[table["label"] == "ours (diff, 1 view)"]
    assert sorted(zip(diff["case"], diff["seed"])) == [("building_1", 0), ("cup_1", 0), ("cup_1", 1)]
    assert set(table.loc[table["case"] == "cup_goblet", "split"]) == {"test"}
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
    assert set(ok.loc[has_rec, "label"]) == {"ours (diff, 1 view)", masked, "ours (GA, 1 view)",
                                             "learned regressor (1 view)"}
    assert (ok.loc[has_rec, "family"] == "in").all() and ok.loc[has_rec, "discrete_match"].between(0, 1).all()
    summary = pd.read_csv(tmp_path / "results/table_summary.csv")
    d = summary[(summary["label"] == "ours (diff, 1 view)") & (summary["case"] == "cup_1")].iloc[0]
    runs = diff.loc[diff["case"] == "cup_1", "iou_mean"]
    assert d["n_seeds"] == 2 and abs(d["iou_mean"] - runs.mean()) < 1e-4 and abs(d["iou_mean_worst"] - runs.min()) < 1e-4
    aggs = set(summary.loc[summary["label"] == "convex hull (reference)", "case"]) - cases
    assert aggs == {"cups/dev/all", "cups/test/all", "trees/dev/all", "buildings/dev/all"}  # in / out: test_table
    md = (tmp_path / "results/table1.md").read_text()
    assert md.index("cups, test split") < md.index("cups, dev split")  # Table 1 is the test split
    html = (tmp_path / "results/report/index.html").read_text()
    assert "Table 1" in html and "ours (diff, 1 view)" in html and "data:image/png;base64" in html
    assert "test split" in html and "Parameter recovery" in html and "Mask errors" in html
    assert (tmp_path / "results/evaluate/diff_1v/cup_1/s1/parts.png").is_file()
    # ours' textures: in the glb and beside it, scored on the two-view folder (view 1 held out)
    fit0 = tmp_path / "results/reconstruct/diff_1v/cup_1/s0"
    assert (fit0 / "textures/body.png").is_file() and "texture" in json.loads((fit0 / "params.json").read_text())
    scores = json.loads((tmp_path / "results/evaluate/diff_1v/cup_1/s0/texture.json").read_text())
    assert scores["inputs"] == 1 and [v["side"] for v in scores["views"]][0] == "input" and len(scores["views"]) == 2
    textures = pd.read_csv(tmp_path / "results/table_texture.csv")
    assert set(textures["case"]) == {"cup_1", "building_1", "tree_1"}
    assert set(textures["label"]) == {"ours (diff, 1 view)", "ours (GA, 1 view)"}  # the GA's trees painted too
    assert (tmp_path / "results/reconstruct/ga_1v/tree_1/s0/textures/foliage.png").is_file()
    assert textures["psnr"].gt(5).all() and textures["ssim"].between(-1, 1).all() and "Textures" in html
    assert (tmp_path / "results/evaluate/diff_1v/cup_1/s1/gallery.png").is_file()
    assert (tmp_path / "results/synth/cup_1/gallery.png").is_file()
    assert table["machine"].notna().all() and not table["machine"].eq("not recorded").any()
    assert (tmp_path / "results/synth/building_1/hemi1/semantic/000.png").is_file()  # window masks for the diff path
    assert json.loads((tmp_path / "results/reconstruct/diff_1v/building_1/s0/params.json").read_text())["generator"] == "buildings"
    assert (tmp_path / "results/evaluate/ga_1v/tree_1/s0/parts.png").is_file()
    assert (tmp_path / "results/prepare/ga/trees/s0.json").is_file()
    # one regressor per generator, read by the learned row and the diff path's start alike
    assert (tmp_path / "results/prepare/learned/dishes/s0.json").is_file()
    assert (tmp_path / "results/prepare/learned/buildings/s0.json").is_file()
    fit = tmp_path / "results/reconstruct/diff_1v/cup_1/s0"
    assert json.loads((fit / "params.json").read_text())["settings"]["start"] == "learned"
    assert "learned" in set(pd.read_csv(fit / "trace.csv")["origin"])
    assert json.loads((tmp_path / "results/reconstruct/learned_1v/cup_1/s0/params.json").read_text())["method"] == "learned"
    assert (tmp_path / "logs/benchmark/reconstruct/diff_1v/cup_1/s0.tsv").is_file()
    wide = pd.read_csv(tmp_path / "results/table_iou.csv", index_col=0)
    assert list(wide.columns)[:4] == ["cup_1", "tree_1", "cup_goblet", "building_1"]
    assert wide.loc["ours (diff, 1 view)", "tree_1"] != wide.loc["ours (diff, 1 view)", "tree_1"]  # NaN: "-"
    assert (tmp_path / "results/synth/cup_1/ring16/transforms.json").is_file()


def test_the_benchmark_config_runs_every_case():
    """``benchmark.yaml`` promises every case of both splits: each case, and each of its rows that
    names cases, covers every case of its generator's class that the row's method can run."""
    import yaml

    from ipm.cases import expand_groups, list_cases, load_case

    cfg = expand_groups(yaml.safe_load((ROOT / "pipelines/config/benchmark.yaml").read_text()))
    assert sorted(cfg["cases"]) == sorted(list_cases())
    for row in (m for m in cfg["methods"] if "cases" in m):
        generators = {load_case(c)["generator"] for c in row["cases"]}
        wanted = {c for c in list_cases() if load_case(c)["generator"] in generators}
        assert set(row["cases"]) == wanted, (row["name"], sorted(wanted - set(row["cases"])))
