"""The workflow on a real SLURM scheduler: a single-node cluster on this machine
(scripts/slurm_local.sh) runs a small DAG through profiles/slurm."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "slurm_local.sh"
STATE = Path(os.environ.get("IPM_SLURM_STATE", "/tmp/ipm-slurm"))
CONFIG = ROOT / "tests" / "data" / "slurm.yaml"
TARGETS = ("results/table.csv", "results/report/index.html")  # the report's browser check is a local rule
DAEMONS = ("munged", "mungekey", "slurmctld", "slurmd", "sbatch", "squeue", "scancel", "sinfo", "scontrol")
PATH = os.environ.get("PATH", "") + ":/usr/sbin:/sbin"


def env() -> dict[str, str]:
    """This environment with the daemons' folder on PATH and no SLURM settings of another cluster
    (the profile reads SBATCH_ACCOUNT and SBATCH_PARTITION)."""
    keep = {k: v for k, v in os.environ.items() if not k.startswith(("SBATCH_", "SLURM_"))}
    return {**keep, "PATH": PATH, "PYTHONUNBUFFERED": "1"}


pytestmark = pytest.mark.slow


def _cannot_run() -> str | None:
    """Why this machine cannot start the cluster, or None."""
    if os.geteuid() != 0:
        return "the single-node SLURM cluster needs root"
    missing = [d for d in DAEMONS if shutil.which(d, path=PATH) is None]
    if missing:
        return f"SLURM packages missing ({' '.join(missing)}; scripts/setup.sh installs them)"
    return None


def _script(action: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), action], capture_output=True, text=True, timeout=120, env=env())


@pytest.fixture(scope="module")
def cluster(request):
    """A started cluster (twice: the second start finds it running), stopped whatever happens."""
    reason = _cannot_run()
    if reason:
        pytest.skip(reason)
    request.addfinalizer(lambda: _script("stop"))
    for _ in range(2):
        res = _script("start")
        assert res.returncode == 0, res.stdout + res.stderr
    assert "idle" in _script("status").stdout
    return STATE


def snakemake_cmd(workdir: Path, *extra: str) -> list[str]:
    """The DAG of tests/data/slurm.yaml through profiles/slurm; status checks from 3 s on (the
    plugin's 40 s suits real jobs, not these few seconds long) and every SLURM log kept."""
    return [sys.executable, "-m", "snakemake", "--snakefile", str(ROOT / "Snakefile"), "--profile",
            str(ROOT / "profiles" / "slurm"), "--configfile", str(CONFIG), "--directory", str(workdir),
            "--slurm-init-seconds-before-status-checks", "3", "--slurm-keep-successful-logs", *extra]


def run(cmd: list[str], timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=ROOT, env=env(), capture_output=True, text=True, timeout=timeout)


def squeue(*args: str) -> list[str]:
    out = subprocess.run(["squeue", "-h", *args], capture_output=True, text=True, env=env())
    return out.stdout.split("\n") if out.returncode == 0 else []


def slurm_jobs(log: str) -> tuple[str, dict[str, dict]]:
    """The run's SLURM run ID (every job's SLURM name) and, by SLURM job id, each cluster job
    Snakemake announced (``rule NAME:`` blocks; local rules print ``localrule``): its rule and
    the memory (MB) and runtime (minutes) Snakemake gave it."""
    run_id = re.search(r"SLURM run ID: (\S+)", log).group(1)
    jobs = {}
    for rule, block in re.findall(r"^rule (\w+):\n((?:    .*\n)+)", log, re.M):
        jobs[re.search(r"jobid: (\d+)", block).group(1)] = {
            "rule": rule, "mem_mb": re.search(r"\bmem_mb=(\d+)", block).group(1),
            "runtime": re.search(r"\bruntime=(\d+)", block).group(1)}
    submitted = dict(re.findall(r"Job (\d+) has been submitted with SLURM jobid (\d+)", log))
    assert set(submitted) == set(jobs), (jobs, submitted)  # every cluster job went to sbatch
    return run_id, {submitted[j]: job for j, job in jobs.items()}


def completions(state: Path) -> dict[str, dict[str, str]]:
    """slurmctld's job-completion log (jobcomp/filetxt): each finished job's fields, by job id."""
    out = {}
    for line in (state / "jobcomp.log").read_text().splitlines():
        fields = dict(f.split("=", 1) for f in line.split() if "=" in f)
        out[fields["JobId"]] = fields
    return out


def test_a_job_larger_than_the_node_fails_at_once(cluster, tmp_path):
    """A job asking more memory than the node has is refused by sbatch: the run fails in
    seconds instead of waiting on a job that can never start."""
    node = subprocess.run(["scontrol", "show", "node"], capture_output=True, text=True, env=env()).stdout
    too_much = int(re.search(r"RealMemory=(\d+)", node).group(1)) + 1000
    start = time.monotonic()
    res = run(snakemake_cmd(tmp_path, "results/synth/cup_1/hemi2", "--set-resources", f"synth:mem_mb={too_much}"),
              timeout=180)
    out = res.stdout + res.stderr
    assert res.returncode != 0, out[-3000:]
    assert "SLURM sbatch failed" in out and "Memory specification can not be satisfied" in out, out[-3000:]
    assert time.monotonic() - start < 120


def test_the_dag_runs_as_slurm_jobs_and_a_killed_job_reruns(cluster, tmp_path):
    """Run 1 (no retries) has one reconstruct job cancelled with scancel while it runs: Snakemake
    reports it failed with SLURM's state and stops; run 2 completes the DAG. Real SLURM jobs:
    each ``rule`` (not ``localrule``) job Snakemake announced was submitted with sbatch, and each
    SLURM job id appears in slurmctld's job-completion log under the run's SLURM name on the
    node (5 COMPLETED and the cancelled one), with its SLURM log file."""
    work = tmp_path / "work"
    with open(tmp_path / "run1.log", "w") as out:
        first = subprocess.Popen(snakemake_cmd(work, "--retries", "0", *TARGETS), cwd=ROOT, env=env(), stdout=out,
                                 stderr=subprocess.STDOUT)
        killed = None
        try:
            deadline = time.monotonic() + 300
            while killed is None and first.poll() is None and time.monotonic() < deadline:
                for line in squeue("-t", "RUNNING", "-o", "%i %k"):
                    if "rule_reconstruct_wildcards_diffsdf" in line:
                        killed = line.split()[0]
                        subprocess.run(["scancel", killed], check=True, env=env())
                time.sleep(0.5)
            first.wait(timeout=300)
        finally:
            if first.poll() is None:
                first.kill()
    log1 = (tmp_path / "run1.log").read_text()
    assert killed is not None, "no reconstruct job was seen running"
    assert first.returncode != 0, log1[-3000:]
    assert "Error in rule reconstruct" in log1 and f"SLURM-job '{killed}' failed" in log1, log1[-3000:]
    assert "CANCELLED" in log1
    res = run(snakemake_cmd(work, *TARGETS))
    log2 = res.stdout + res.stderr
    assert res.returncode == 0, log2[-3000:]

    id1, jobs1 = slurm_jobs(log1)
    id2, jobs2 = slurm_jobs(log2)
    rules1, rules2 = ([job["rule"] for job in jobs.values()] for jobs in (jobs1, jobs2))
    assert jobs1[killed]["rule"] == "reconstruct" and "synth" in rules1
    assert "synth" not in rules2 and "reconstruct" in rules2  # the rest, and only the rest
    assert sorted(rules1 + rules2) == ["evaluate"] * 2 + ["reconstruct"] * 3 + ["synth"]
    done = completions(cluster)
    for run_id, jobs in ((id1, jobs1), (id2, jobs2)):
        for job_id, job in jobs.items():
            rec = done[job_id]
            assert rec["Name"] == run_id and rec["NodeList"] == os.uname().nodename.split(".")[0], rec
            assert rec["JobState"] == ("CANCELLED" if job_id == killed else "COMPLETED"), rec
            # the rule's resources reached SLURM: its memory, its runtime as the time limit, one CPU
            assert f"mem={job['mem_mb']}M" in rec["Tres"] and "cpu=1," in rec["Tres"], rec
            assert rec["TimeLimit"] == job["runtime"], rec
            assert list((work / ".snakemake/slurm_logs" / f"rule_{job['rule']}").glob(f"*/{job_id}.log"))
    assert sum(r["Name"] in (id1, id2) for r in done.values()) == 6  # no SLURM job beyond those

    table = pd.read_csv(work / "results/table.csv")
    assert set(table["case"]) == {"cup_1"}
    assert set(table["label"]) == {"visual hull (2 views)", "diffSDF-style (2 views)"}
    assert table["iou_mean"].between(0, 1).all()
    html = (work / "results/report/index.html").read_text()
    assert "Table 1" in html and "visual hull (2 views)" in html
