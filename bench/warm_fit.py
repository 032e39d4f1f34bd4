"""Benchmark: a single-view fit as a user runs it, ``ipm reconstruct --views ...``, a new process
per fit with JAX's compilation cache warm (one run first that is not counted), on ``--threads``
CPU threads. Prints and writes each case's median wall time of the whole command and of the fit
(``timing.json``: from the views read to the mesh written), each run's seconds by stage of the
search (its trace), and checks the targets on the fit
(:data:`TARGETS_S`: a warm cup within 10 s, a warm building within 45 s, on 2 CPU threads; the
whole command adds the imports, about 1.2 s).

    .venv/bin/python bench/warm_fit.py [--cases cup_1 cup_2 cup_d1] [--runs 3] [--threads 2]
        [--seed 0] [--out results/bench/warm_fit.json]
    .venv/bin/python bench/warm_fit.py --cases building_d3 building_d11 building_d20

The cases' views are synthesized first (256 px, as the default run's). Run it with nothing else
on the machine: a job beside it shares the cores.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TARGETS_S = {"dishes": 10.0, "buildings": 45.0}
"""A warm fit on 2 CPU threads, at most (seconds), per generator."""


def stage_seconds(trace) -> list[dict]:
    """A fit's trace (trace.csv) as its stages in order, each run of rows of one stage and width
    with its evaluations and seconds (from the stage before's last row to its own last: the work
    between two stages is the later one's)."""
    block = ((trace["stage"] != trace["stage"].shift()) | (trace["res"] != trace["res"].shift())).cumsum()
    rows, before = [], 0.0
    for _, part in trace.groupby(block, sort=True):
        end = float(part["seconds"].iloc[-1])
        rows.append({"stage": str(part["stage"].iloc[0]), "res": int(part["res"].iloc[0]), "evaluations": len(part),
                     "seconds": round(end - before, 2)})
        before = end
    return rows


def merged(stages: list[dict]) -> list[dict]:
    """:func:`stage_seconds`' consecutive entries of one stage as one (a race's steps and its scores
    at another width alternate): evaluations and seconds added, the widths joined ("128/256")."""
    out = []
    for s in stages:
        if out and out[-1]["stage"] == s["stage"]:
            last = out[-1]
            widths = last["res"].split("/")
            last["res"] = "/".join(widths + [str(s["res"])] if str(s["res"]) not in widths else widths)
            last["evaluations"] += s["evaluations"]
            last["seconds"] = round(last["seconds"] + s["seconds"], 2)
        else:
            out.append({**s, "res": str(s["res"])})
    return out


def timed_fit(generator: str, views: Path, out: Path, threads: int, seed: int) -> tuple[float, float, list[dict]]:
    """Wall seconds of one ``ipm reconstruct`` command, its fit's seconds (timing.json) and its
    stages' (:func:`stage_seconds`)."""
    import pandas as pd

    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "ipm.cli", "reconstruct", "--generator", generator, "--views", str(views),
                    "--out", str(out), "--threads", str(threads), "--seed", str(seed), "--quiet"], check=True,
                   capture_output=True)
    wall = time.perf_counter() - t0
    stages = stage_seconds(pd.read_csv(out / "trace.csv"))
    return wall, float(json.loads((out / "timing.json").read_text())["seconds"]), stages


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["cup_1", "cup_2", "cup_d1"])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/bench/warm_fit.json")
    args = ap.parse_args()
    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant

    configure_threads(args.threads, "cpu")
    set_mitsuba_variant("cpu", args.threads)
    from ipm.cases import load_case
    from ipm.synth import synthesize

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            src = Path(tmp) / case
            generator = load_case(case)["generator"]
            synthesize(case, src, n_views=1, res=256, spp=32, progress=False)
            timed_fit(generator, src / "transforms.json", Path(tmp) / "out", args.threads, args.seed)  # warms the cache
            runs = [timed_fit(generator, src / "transforms.json", Path(tmp) / "out", args.threads, args.seed)
                    for _ in range(args.runs)]
            wall, fit = np.median([r[0] for r in runs]), np.median([r[1] for r in runs])
            middle = runs[int(np.argsort([r[1] for r in runs])[len(runs) // 2])][2]  # the median fit's stages
            rows.append({"case": case, "generator": generator, "wall_s": round(float(wall), 2), "fit_s": round(float(fit), 2),
                         "runs": [[round(w, 2), round(f, 2)] for w, f, _ in runs], "stages": [r[2] for r in runs]})
            print(f"{case}: whole command {wall:.1f} s, fit {fit:.1f} s (median of {args.runs}); its stages: "
                  + ", ".join(f"{s['stage']}@{s['res']} {s['seconds']:.1f} s ({s['evaluations']})"
                              for s in merged(middle)),
                  flush=True)
    met = {g: all(r["fit_s"] <= TARGETS_S[g] for r in rows if r["generator"] == g)
           for g in dict.fromkeys(r["generator"] for r in rows) if g in TARGETS_S}  # per generator with a target
    if args.threads == 2:
        for generator, ok in met.items():
            print(f"target: a warm {generator} fit within {TARGETS_S[generator]:g} s on 2 threads: "
                  f"{'met' if ok else 'NOT met'}")
    from ipm.io import write_json

    write_json(args.out, {"machine": machine_info(args.threads), "threads": args.threads,
                          "seed": args.seed, "cases": rows, "targets_s": TARGETS_S, "target_met": all(met.values())})


if __name__ == "__main__":
    main()
