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
    """The DAG of tests/data/slurm.yaml through profiles/slurm; status checks from 3 s on and every
    2 s (the plugin's 40 s and Snakemake's 10 s suit real jobs, not these few seconds long) and
    every SLURM log kept."""
    return [sys.executable, "-m", "snakemake", "--snakefile", str(ROOT / "Snakefile"), "--profile",
            str(ROOT / "profiles" / "slurm"), "--configfile", str(CONFIG), "--directory", str(workdir),
            "--slurm-init-seconds-before-status-checks", "3", "--seconds-between-status-checks", "2",
            "--slurm-keep-successful-logs", *extra]


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
    submitted = re.findall(r"Job (\d+) has been submitted with SLURM jobid (\d+)", log)  # a retry: again
    assert {j for j, _ in submitted} == set(jobs), (jobs, submitted)  # every cluster job went to sbatch
    return run_id, {slurm_id: jobs[j] for j, slurm_id in submitted}


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
    """The DAG's first cluster job, the synth, is cancelled with scancel while it runs: Snakemake
    reports it failed with SLURM's state, submits it again (the profile's ``retries: 1``) and
    completes the DAG. Real SLURM jobs: each ``rule`` (not ``localrule``) job Snakemake announced
    was submitted with sbatch, and each SLURM job id appears in slurmctld's job-completion log
    under the run's SLURM name, on the node, with the rule's memory, time limit and CPUs (5
    COMPLETED and the cancelled one, no other), and has its SLURM log file."""
    work = tmp_path / "work"
    with open(tmp_path / "run.log", "w") as out:
        proc = subprocess.Popen(snakemake_cmd(work, *TARGETS), cwd=ROOT, env=env(), stdout=out,
                                stderr=subprocess.STDOUT)
        killed = None
        try:
            deadline = time.monotonic() + 300
            while killed is None and proc.poll() is None and time.monotonic() < deadline:
                for line in squeue("-t", "RUNNING", "-o", "%i %k"):
                    if "rule_synth_wildcards" in line:
                        killed = line.split()[0]
                        subprocess.run(["scancel", killed], check=True, env=env())
                time.sleep(0.5)
            proc.wait(timeout=600)
        finally:
            if proc.poll() is None:
                proc.kill()
    log = (tmp_path / "run.log").read_text()
    assert killed is not None, "no synth job was seen running"
    assert proc.returncode == 0, log[-3000:]
    failed = f"Error in rule synth:\n    message: SLURM-job '{killed}' failed, SLURM status is: 'CANCELLED'"
    assert failed in log and "Trying to restart job" in log, log[-3000:]

    run_id, jobs = slurm_jobs(log)
    assert sorted(job["rule"] for job in jobs.values()) == ["evaluate"] * 2 + ["reconstruct"] * 2 + ["synth"] * 2
    done = completions(cluster)
    for job_id, job in jobs.items():
        rec = done[job_id]
        assert rec["Name"] == run_id and rec["NodeList"] == os.uname().nodename.split(".")[0], rec
        assert rec["JobState"] == ("CANCELLED" if job_id == killed else "COMPLETED"), rec
        # the rule's resources reached SLURM: its memory, its runtime as the time limit, one CPU
        assert f"mem={job['mem_mb']}M" in rec["Tres"] and "cpu=1," in rec["Tres"], rec
        assert rec["TimeLimit"] == job["runtime"], rec
        assert list((work / ".snakemake/slurm_logs" / f"rule_{job['rule']}").glob(f"*/{job_id}.log"))
    assert sum(r["Name"] == run_id for r in done.values()) == 6  # no SLURM job beyond those

    table = pd.read_csv(work / "results/table.csv")
    assert set(table["case"]) == {"cup_1"}
    assert set(table["label"]) == {"visual hull (2 views)", "diffSDF-style (2 views)"}
    assert table["iou_mean"].between(0, 1).all()
    html = (work / "results/report/index.html").read_text()
    assert "Table 1" in html and "visual hull (2 views)" in html
