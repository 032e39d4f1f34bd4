"""Benchmark: the tree GA against random search and CMA-ES at the same number of evaluations.

    .venv/bin/python bench/ga_peers.py [--case tree_1] [--profile default] [--budget N]
        [--seed 0] [--algorithms ga random cma] [--stats results/prepare/ga/trees.json]
        [--out results/bench/ga_peers]

All three minimise the same objective as ``ipm reconstruct --method ga`` (the tree loss of the
case's input view, ``ipm.methods.ga.problem_objective``) over the same unit-cube genome, each for
``--budget`` evaluations (default: the paper's 5000). Writes ``curves.csv`` (best loss
after each evaluation per algorithm), ``curves.png``, and ``summary.json``: per algorithm the
best objective loss, its tree similarity (TSim without multipliers, in the input view), the
64-view IoU of its mesh against the reference, and wall time; plus the GA's similarity and IoU
over each peer's (the ratios issue 4 asks for). The case's one input view is rendered into
``OUT/views`` unless ``--views`` gives a transforms.json.

    .venv/bin/python bench/ga_peers.py --aggregate DIR [DIR ...] [--out OUT]

combines the ``summary.json`` of runs with other seeds into ``OUT/aggregate.json``: per
algorithm the values of every seed and their means, and the GA's mean similarity over each
peer's.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

PROGRESS = True
"""Progress bars (off with --quiet)."""


def _views(args) -> Path:
    if args.views:
        return Path(args.views)
    path = Path(args.out) / "views" / "transforms.json"
    if not path.exists():
        from ipm.runtime import set_mitsuba_variant
        from ipm.synth import synthesize

        set_mitsuba_variant("cpu", args.threads)
        synthesize(args.case, path.parent, n_views=1, res=args.res, spp=64, progress=False)
    return path


def run_ga(objective, settings, stats, budget: int, seed: int):
    from ipm.optim.ga import TreeGA

    best, _, trace = TreeGA(objective.genome.spec, settings, stats, seed=seed).minimize(objective, budget, progress=PROGRESS)
    return best, trace["loss"].to_numpy()


def run_random(objective, budget: int, seed: int):
    from tqdm import tqdm

    from ipm.optim.ga import random_genes

    genes = random_genes(objective.genome.spec, np.random.default_rng(seed), budget)
    losses = np.array([objective(g) for g in tqdm(genes, desc="random", leave=False, disable=not PROGRESS)])
    return genes[int(np.argmin(losses))], losses


def run_cma(objective, budget: int, seed: int, sigma0: float = 0.3):
    """CMA-ES (the ``cma`` package) on the unit cube, bounds [0, 1], discrete genes snapped
    before evaluation, started at the cube's centre; the last generation is cut at the budget."""
    import cma
    from tqdm import tqdm

    from ipm.optim.ga import snap

    spec = objective.genome.spec
    es = cma.CMAEvolutionStrategy(np.full(len(spec), 0.5), sigma0,
                                  {"bounds": [0.0, 1.0], "seed": seed + 1, "verbose": -9})
    losses, best, best_loss = [], None, np.inf
    with tqdm(total=budget, desc="cma", leave=False, disable=not PROGRESS) as bar:
        while len(losses) < budget:
            xs = es.ask()
            fs = []
            for x in xs[: budget - len(losses)]:
                g = snap(spec, x)
                f = objective(g)
                fs.append(f)
                losses.append(f)
                if f < best_loss:
                    best, best_loss = g, f
                bar.update(1)
            if len(fs) < len(xs):
                break
            es.tell(xs, fs)
    return best, np.array(losses)


def describe(objective, g, reference, options) -> dict:
    """Objective loss, TSim in the input view and 64-view IoU of genome ``g``."""
    from ipm.losses.tree import TreeStats, loss_terms
    from ipm.metrics import silhouette_iou
    from ipm.methods.ga import output_lod

    images, _ = objective.render(g)
    target = objective.targets[0]
    tsim = loss_terms(target.stats, TreeStats(images[0][0]), [], stripe_height=None,
                      n_stripes=options.n_stripes)["tsim"]
    mesh, _ = objective.genome.world_mesh(g, output_lod(objective.genome.generator, options))
    import trimesh

    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    iou = silhouette_iou(reference, tm, n_views=64, res=256)["iou_mean"]
    return {"loss": float(objective(g)), "tsim": float(tsim), "iou64": float(iou)}


def aggregate(dirs: list[str], out: Path) -> dict:
    """Per-seed values and means of every algorithm over the runs in ``dirs`` (their summary.json)."""
    from ipm.io import write_json

    runs = [json.loads((Path(d) / "summary.json").read_text()) for d in dirs]
    algs: dict = {}
    for run in runs:
        for name, r in run["algorithms"].items():
            a = algs.setdefault(name, {"seeds": [], "loss": [], "tsim": [], "iou64": []})
            a["seeds"].append(run["seed"])
            for k in ("loss", "tsim", "iou64"):
                a[k].append(r[k])
    for a in algs.values():
        for k in ("loss", "tsim", "iou64"):
            a[f"mean_{k}"] = float(np.mean(a[k]))
    out_d = {"case": runs[0]["case"], "budget": runs[0]["budget"], "runs": [str(d) for d in dirs], "algorithms": algs}
    if "ga" in algs:
        out_d["ga_over_peer_mean_similarity"] = {
            p: (1 - algs["ga"]["mean_loss"]) / max(1 - a["mean_loss"], 1e-12) for p, a in algs.items() if p != "ga"}
    write_json(out / "aggregate.json", out_d)
    return out_d


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="tree_1")
    ap.add_argument("--views", default=None, help="transforms.json of the input view (default: rendered)")
    ap.add_argument("--res", type=int, default=256, help="input view size when rendered here")
    ap.add_argument("--profile", default="default")
    ap.add_argument("--budget", type=int, default=5000, help="evaluations per algorithm (the paper's 5000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--algorithms", nargs="+", default=["ga", "random", "cma"], choices=["ga", "random", "cma"])
    ap.add_argument("--stats", default="results/prepare/ga/trees.json",
                    help="GA statistics (ipm prepare ga); collected into OUT if missing")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default="results/bench/ga_peers")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    ap.add_argument("--aggregate", nargs="+", default=None, metavar="DIR",
                    help="only combine the summary.json of earlier runs into OUT/aggregate.json")
    args = ap.parse_args()
    if args.aggregate:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        print(json.dumps(aggregate(args.aggregate, Path(args.out)), indent=1))
        return
    global PROGRESS
    PROGRESS = not args.quiet

    from ipm.runtime import configure_threads

    configure_threads(args.threads)
    import pandas as pd

    from ipm.generators import get_generator
    from ipm.io import load_mesh, load_views, write_json
    from ipm.methods.ga import collect_generator_statistics, get_options, problem_objective
    from ipm.optim.ga import GeneStatistics, get_settings
    from ipm.synth import load_case, write_reference

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    views_path = _views(args)
    generator = load_case(args.case)["generator"]
    ref_path = out / "reference" / "reference.ply"
    if not ref_path.exists():
        write_reference(args.case, ref_path.parent)
    reference = load_mesh(ref_path)
    settings = get_settings(args.profile)
    budget = args.budget
    options = get_options(args.profile)
    stats_path = Path(args.stats)
    if not stats_path.exists():
        stats_path = out / f"stats_{generator}.json"
        if not stats_path.exists():
            collect_generator_statistics(generator, stats_path, profile=args.profile, seed=args.seed,
                                         progress=PROGRESS)
    stats = GeneStatistics.load(stats_path)
    objective = problem_objective(load_views(views_path), get_generator(generator), options)
    stats.check(objective.genome.spec)

    summary = {"case": args.case, "profile": args.profile, "budget": budget, "seed": args.seed,
               "statistics": str(stats_path), "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
               "threads": args.threads, "algorithms": {}}
    curves = {}
    for name in args.algorithms:
        t0 = time.perf_counter()
        if name == "ga":
            best, losses = run_ga(objective, settings, stats, budget, args.seed)
        elif name == "random":
            best, losses = run_random(objective, budget, args.seed)
        else:
            best, losses = run_cma(objective, budget, args.seed)
        seconds = time.perf_counter() - t0
        curves[name] = np.minimum.accumulate(losses)
        summary["algorithms"][name] = {**describe(objective, best, reference, options), "seconds": seconds,
                                       "evaluations": int(len(losses))}
        print(f"{name}: {summary['algorithms'][name]}", flush=True)
    algs = summary["algorithms"]
    if "ga" in algs:
        summary["ga_over_peer"] = {
            peer: {"tsim": algs["ga"]["tsim"] / max(algs[peer]["tsim"], 1e-12),
                   "similarity": (1 - algs["ga"]["loss"]) / max(1 - algs[peer]["loss"], 1e-12),
                   "iou64": algs["ga"]["iou64"] / max(algs[peer]["iou64"], 1e-12)}
            for peer in algs if peer != "ga"}
    rows = [(name, i + 1, float(v)) for name, c in curves.items() for i, v in enumerate(c)]
    pd.DataFrame(rows, columns=["algorithm", "evaluations", "best_loss"]).to_csv(out / "curves.csv", index=False)
    write_json(out / "summary.json", summary)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, c in curves.items():
        ax.plot(np.arange(1, len(c) + 1), c, label=f"{name} (64-view IoU {algs[name]['iou64']:.3f})")
    ax.set_xlabel("evaluations")
    ax.set_ylabel("best objective loss (1 - similarity)")
    ax.set_title(f"{args.case}: GA vs peers, {budget} evaluations")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=120)
    print(json.dumps(summary.get("ga_over_peer", {}), indent=1))


if __name__ == "__main__":
    main()
