"""Benchmark: where a command's CPU time goes in JAX's compiler: XLA's backend compiles, tracing
and lowering, by program and by pytest test, with the persistent cache's hits and misses, and the
programs compiled again for the same argument shapes (what differs is baked in: a span budget, a
setting). Every Python process the command starts (test workers, the CLI, the smoke DAG's jobs)
records itself (``bench/compile_hook``); the summary adds them up. Run with nothing else on the
machine.

    .venv/bin/python bench/compile_profile.py [--out results/bench/compile_profile.json] [--top 25] [--keep FOLDER]
        [-- COMMAND ...]      # default: the whole test suite, .venv/bin/python -m pytest -q
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from contextlib import nullcontext
from pathlib import Path

from ipm.io.atomic import write_json

HOOK = Path(__file__).resolve().parent / "compile_hook"


def profiled_run(command: list[str], folder: Path) -> tuple[int, float]:
    """Run ``command`` with every Python process it starts recording into ``folder``; its exit
    status and wall seconds."""
    env = {**os.environ, "IPM_COMPILE_PROFILE": str(folder),
           "PYTHONPATH": os.pathsep.join(p for p in (str(HOOK), os.environ.get("PYTHONPATH", "")) if p)}
    t0 = time.perf_counter()
    rc = subprocess.run(command, env=env).returncode
    return rc, time.perf_counter() - t0


def read_processes(folder: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(folder.glob("*.json"))]


_TOTAL = {"compile": "compile_s", "trace": "trace_s", "lower": "lower_s", "read": "read_s", "hit": "hits",
          "miss": "misses"}


def summarize(processes: list[dict], top: int = 25) -> dict:
    """Totals (processes' CPU, compile, trace, lower, cache reads), per program (compiles, their
    seconds, cache hits) and per test (compile + trace + lower seconds), the largest ``top`` each."""
    totals = Counter(cpu_s=sum(p["cpu_s"] for p in processes))
    programs: dict = defaultdict(Counter)
    tests: Counter = Counter()
    shapes: dict = defaultdict(Counter)  # (program, argument shapes) -> compiles, seconds
    keys: dict = defaultdict(Counter)  # cache key (the program's name and a hash) -> compiles, seconds
    for p in processes:
        for kind, test, program, seconds, *rest in p["records"]:
            totals[_TOTAL[kind]] += seconds if _TOTAL[kind].endswith("_s") else 1
            if kind == "compile":
                programs[program or "?"].update(compiles=1, seconds=seconds)
                if rest and rest[0] and program:  # unnamed (uncached) programs differ beyond their shapes
                    shapes[program, rest[0]].update(compiles=1, seconds=seconds)
                if len(rest) > 1 and rest[1]:
                    keys[rest[1]].update(compiles=1, seconds=seconds)
            elif kind == "hit":
                programs[program or "?"].update(hits=1)
            if kind in ("compile", "trace", "lower"):
                tests[test] += seconds
    ranked = sorted(programs.items(), key=lambda kv: -kv[1]["seconds"])[:top]
    again = sorted(((k, c) for k, c in shapes.items() if c["compiles"] > 1), key=lambda kv: -kv[1]["seconds"])[:top]
    # the same program (cache key) compiled more than once: in processes side by side, each before
    # the other had written it, or read back by none (evicted)
    repeated = [c["seconds"] * (c["compiles"] - 1) / c["compiles"] for c in keys.values() if c["compiles"] > 1]
    totals.update(same_program_again_s=sum(repeated))
    return {"processes": len(processes), "totals": {k: round(v, 3) for k, v in totals.items()},
            "programs": [{"program": name, "compiles": c["compiles"], "seconds": round(c["seconds"], 3),
                          "hits": c["hits"]} for name, c in ranked],
            "tests": [{"test": t, "seconds": round(s, 3)} for t, s in tests.most_common(top)],
            "same_shapes": [{"program": name, "shapes": args, "compiles": c["compiles"], "seconds": round(c["seconds"], 3)}
                            for (name, args), c in again]}


def markdown(summary: dict) -> str:
    t = summary["totals"]
    lines = [f"{summary['processes']} processes, {t.get('cpu_s', 0):.0f} s CPU: backend compile "
             f"{t.get('compile_s', 0):.0f} s, tracing {t.get('trace_s', 0):.0f} s, lowering {t.get('lower_s', 0):.0f} s, "
             f"cache reads {t.get('read_s', 0):.0f} s ({t.get('hits', 0):.0f} hits, {t.get('misses', 0):.0f} "
             f"misses); the same program compiled again {t.get('same_program_again_s', 0):.0f} s",
             "", "| program | compiles | seconds | cache hits |", "|---|---|---|---|"]
    lines += [f"| {p['program']} | {p['compiles']} | {p['seconds']} | {p['hits']} |" for p in summary["programs"]]
    lines += ["", "| test | compile + trace + lower (s) |", "|---|---|"]
    lines += [f"| {r['test']} | {r['seconds']} |" for r in summary["tests"]]
    if summary.get("same_shapes"):
        lines += ["", "| program compiled again for the same argument shapes | compiles | seconds |", "|---|---|---|"]
        lines += [f"| {r['program']} {r['shapes'][:160]} | {r['compiles']} | {r['seconds']} |"
                  for r in summary["same_shapes"]]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("results/bench/compile_profile.json"))
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--keep", type=Path, help="keep every process's records in this folder (default: a temporary one)")
    ap.add_argument("command", nargs="*", help="the command to profile (after --); default: the test suite")
    args = ap.parse_args(argv)
    command = args.command or [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"]
    with nullcontext(args.keep) if args.keep else tempfile.TemporaryDirectory(prefix="ipm-compile-profile-") as folder:
        records = Path(folder)
        records.mkdir(parents=True, exist_ok=True)
        rc, wall = profiled_run(command, records)
        summary = {"command": [Path(command[0]).name, *command[1:]], "exit_status": rc, "wall_s": round(wall, 1),
                   **summarize(read_processes(records), args.top)}
    print(markdown(summary))
    write_json(args.out, summary)  # atomically, its folder made
    return rc


if __name__ == "__main__":
    sys.exit(main())
