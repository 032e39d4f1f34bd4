"""Benchmark: whole single-view fits (diff path, JAX renderer) with their wall time split into
steady evaluations and one-off events (a stage's first call: tracing, compiling or loading its
program).

    .venv/bin/python bench/cup_fits.py [--device cpu|cuda] [--threads 2] [--cases cup_1 cup_2]
        [--seeds 1 2] [--out results/bench/cup_fits]

Each fit runs in this process with JAX's persistent compilation cache as configured (on by
default: run a seed once first to time warm fits, as the workflow's next seed is). Later fits in
one process reuse its traced programs; to time what a workflow job pays (a new process loading
the stored programs, ``ipm.render.programs``), run it once per fit. Writes each
fit's folder (``ipm.methods.diff.write_fit``: trace.csv, params.json) under ``--out`` and one
JSON line per fit (with the machine and its CPU kind) to ``--out``/fits.jsonl; prints the same
lines. A trace row's time is its evaluation's; a row more than ``--event-ms`` after the one before
counts as an event.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd


def split_time(trace: pd.DataFrame, event_s: float) -> dict:
    """Seconds of a fit's trace in steady evaluations and in events (gaps over ``event_s``), the
    evaluations' median milliseconds, and the memetic stage's seconds."""
    dt = trace["seconds"].diff().fillna(trace["seconds"].iloc[0]).to_numpy()
    event = dt > event_s
    memetic = trace["stage"].to_numpy() == "memetic"
    return {"seconds_steady": round(float(dt[~event].sum()), 2), "seconds_events": round(float(dt[event].sum()), 2),
            "events": int(event.sum()), "median_eval_ms": round(1000 * float(np.median(dt)), 2),
            "memetic_s": round(float(dt[memetic].sum()), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--profile", default="default")
    ap.add_argument("--cases", nargs="+", default=["cup_1", "cup_2"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--input-res", type=int, default=256)
    ap.add_argument("--event-ms", type=float, default=50.0)
    ap.add_argument("--out", default="results/bench/cup_fits")
    args = ap.parse_args()

    from ipm.runtime import configure_threads, set_mitsuba_variant

    configure_threads(args.threads, args.device)
    set_mitsuba_variant(args.device, args.threads)
    import jax

    from ipm.io import load_views
    from ipm.methods.diff import fit, write_fit
    from ipm.synth import synthesize

    from ipm.runtime import machine_info, machine_line

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    device = str(jax.devices()[0])
    machine = machine_line(machine_info(args.threads, args.device))  # with the CPU's kind: times differ by it
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            synthesize(case, Path(tmp) / case, n_views=1, res=args.input_res, spp=32, progress=False)
            generator = json.loads((Path(tmp) / case / "ground_truth.json").read_text())["generator"]
            views = load_views(Path(tmp) / case / "transforms.json").subset([0])
            for seed in args.seeds:
                t0 = time.perf_counter()
                problem, z, trace, prof = fit(views, generator, args.profile, seed, False, renderer="jax")
                seconds = time.perf_counter() - t0
                write_fit(out / f"{case}_s{seed}", problem, z, trace, prof, {}, seconds)
                row = {"case": case, "seed": seed, "device": device, "machine": machine,
                       "seconds": round(seconds, 2), "evaluations": len(trace),
                       "final_loss": float(trace["best"].iloc[-1]), **split_time(trace, args.event_ms / 1000)}
                print(json.dumps(row), flush=True)
                with open(out / "fits.jsonl", "a") as f:
                    f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
