"""Benchmark: wall time of one trees-generator call (mesh + branch graph) per preset and level of detail.

    .venv/bin/python bench/tree_generator_speed.py [--threads 1] [--repeats 20]
        [--random 20] [--out results/bench/tree_generator_speed.json]

Prints the median milliseconds per call with the mesh size, for every preset at every level of
detail and for random parameter vectors in bounds (lowest level of detail), and writes the
numbers as JSON with the machine's description. Target: well under 50 ms per preset call at the
lowest level of detail, so the genetic search can afford thousands of evaluations.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def _time(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` in milliseconds after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    times.sort()
    return 1e3 * times[len(times) // 2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=20, help="timed calls per preset and level of detail")
    ap.add_argument("--random", type=int, default=20, help="random parameter vectors (lowest level of detail)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/bench/tree_generator_speed.json")
    args = ap.parse_args()

    from ipm.runtime import configure_threads, machine_info

    configure_threads(args.threads)
    import numpy as np

    from ipm.generators import get_generator

    gen = get_generator("trees")
    rows = []
    print(f"{'preset':<10}{'lod':>4}{'ms/call':>10}{'vertices':>10}{'triangles':>11}{'graph':>8}{'leaves':>8}")
    for name, x in gen.presets.items():
        for lod in gen.lods:
            ms = _time(lambda: gen.generate(x, lod), args.repeats)
            m, g = gen.generate(x, lod)
            rows.append(dict(preset=name, lod=lod, ms=ms, vertices=len(m.vertices), triangles=len(m.faces),
                             graph_vertices=g.n_vertices, leaves=g.n_leaves))
            print(f"{name:<10}{lod:>4}{ms:>10.1f}{len(m.vertices):>10}{len(m.faces):>11}"
                  f"{g.n_vertices:>8}{g.n_leaves:>8}")

    rng = np.random.default_rng(args.seed)
    lod = min(gen.lods)
    rand = []
    for _ in range(args.random):
        x = gen.spec.from_unit(rng.random(len(gen.spec)))
        rand.append(_time(lambda: gen.generate(x, lod), 3))
    if rand:
        print(f"random vectors (lod {lod}, n={len(rand)}): median {np.median(rand):.1f} ms, "
              f"90th percentile {np.percentile(rand, 90):.1f} ms, max {max(rand):.1f} ms")

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "machine": machine_info(args.threads),
        "presets": rows,
        "random_lowest_lod_ms": rand,
    }, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
