"""The report's provenance: the commit, the packages' versions, the configuration and the machines
the runs ran on (``reports.build``)."""
from __future__ import annotations

import json
import platform
import subprocess
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

import pandas as pd

HERE = Path(__file__).parent
PACKAGES = ("mitsuba", "drjit", "jax", "jaxlib", "numpy", "open3d", "pycolmap", "trimesh", "pandas", "snakemake")
"""Packages whose versions the provenance lists (read from their metadata, nothing imported)."""


def _git_commit() -> str:
    """HEAD of the repository of the working directory, else of the one this code lies in (with a
    mark when tracked files differ from it), else "unknown"."""
    for where in (Path.cwd(), HERE.parent):
        try:
            head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True,
                                  timeout=10, check=True)
            dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
                                   capture_output=True, text=True, timeout=10, check=True)
        except (OSError, subprocess.SubprocessError):
            continue
        return head.stdout.strip() + (" (with uncommitted changes)" if dirty.stdout.strip() else "")
    return "unknown"


def _versions() -> dict:
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _machines(df: pd.DataFrame) -> list[dict]:
    """Per machine (table.csv's ``machine``; "not recorded" where absent) the runs that ran there:
    a line per method, "label: case (seeds ...), ..."."""
    machine = df["machine"] if "machine" in df else pd.Series("not recorded", index=df.index)
    machine = machine.fillna("not recorded").replace("", "not recorded")
    out = []
    for name, g in df.assign(machine=machine).groupby("machine", sort=False):
        runs = [f"{label}: " + ", ".join(f"{case} (seed{'s' if len(c) > 1 else ''} "
                                         f"{', '.join(str(int(s)) for s in c['seed'])})"
                                         for case, c in lg.groupby("case", sort=False))
                for label, lg in g.groupby("label", sort=False)]
        out.append({"name": name, "n": len(g), "runs": runs})
    return out


def _provenance(df: pd.DataFrame, config: dict) -> dict:
    import yaml

    from ipm.runtime import machine_info, machine_line

    plain = json.loads(json.dumps(config, default=str))
    return {"versions": _versions(), "commit": _git_commit(), "config": yaml.safe_dump(plain, sort_keys=False),
            "machines": _machines(df), "built_on": machine_line(machine_info()),
            "built_at": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}
