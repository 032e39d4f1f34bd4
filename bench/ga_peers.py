"""Benchmark: the tree GA against random search and CMA-ES at the same number of evaluations.

    .venv/bin/python bench/ga_peers.py [--case tree_1] [--profile default] [--budget N]
        [--seeds 0 1 2] [--algorithms ga random cma] [--stats FILE] [--out results/bench/ga_peers]

All three minimise the same objective as ``ipm reconstruct --method ga`` (the tree loss of the
case's input view, ``ipm.losses.tree_objective``, built by ``problem_objective``) over the same unit-cube genome. The
budget counts every evaluation of an objective: the GA searches for ``--budget`` evaluations
(default 5000, the authors' code configuration; the paper's text gives 50 000 for trees) after
its gene statistics, which cost ``2 * stats_samples`` evaluations more (2000 in the default
profile) and are collected anew for each seed with that seed; random search and CMA-ES get the
sum. With ``--stats FILE`` the GA reuses one statistics file for every seed, and its cost is
still added to the peers' budget.

Per seed, ``OUT/seed<S>/`` gets ``curves.csv`` (best loss after each evaluation per algorithm,
the GA's curve starting after its statistics), ``curves.png`` and ``summary.json``: per
algorithm the best objective loss, its tree similarity (TSim without multipliers, in the input
view), the 64-view IoU of its mesh against the reference, wall time and evaluations. ``OUT/``
gets ``aggregate.json`` over the seeds: per algorithm every seed's values, their mean, standard
deviation and worst, and the GA's mean similarity over each peer's. The case's one input view is
rendered into ``OUT/views`` unless ``--views`` gives a transforms.json.

    .venv/bin/python bench/ga_peers.py --aggregate DIR [DIR ...] [--out OUT]

combines the ``summary.json`` of earlier runs into ``OUT/aggregate.json``.
"""
from __future__ import annotations

import argparse
import json
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

    from ipm.optim.ga_statistics import random_genes

    genes = random_genes(objective.genome.spec, np.random.default_rng(seed), budget)
    losses = np.array([objective(g) for g in tqdm(genes, desc="random", leave=False, disable=not PROGRESS)])
    return genes[int(np.argmin(losses))], losses


def run_cma(objective, budget: int, seed: int, sigma0: float = 0.3):
    """CMA-ES (the ``cma`` package) on the unit cube, bounds [0, 1], discrete genes snapped
    before evaluation, started at the cube's centre; the last generation is cut at the budget."""
    import cma
    from tqdm import tqdm

    from ipm.optim.ga_statistics import snap

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
    from ipm.methods.ga_options import output_lod

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
    from ipm.io import shown_path, write_json

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
            a[f"std_{k}"] = float(np.std(a[k]))
        a["worst_loss"], a["worst_iou64"] = float(np.max(a["loss"])), float(np.min(a["iou64"]))
    out_d = {"case": runs[0]["case"], "budget": runs[0]["budget"],
             "statistics_evaluations": runs[0].get("statistics_evaluations"), "runs": [shown_path(d) for d in dirs],
             "algorithms": algs}
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
    ap.add_argument("--budget", type=int, default=5000,
                    help="GA search evaluations (the authors' code configuration; the peers get this plus the "
                         "GA's statistics evaluations)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--algorithms", nargs="+", default=["ga", "random", "cma"], choices=["ga", "random", "cma"])
    ap.add_argument("--stats", default=None,
                    help="one GA statistics file (ipm prepare ga) for every seed; default: collected per seed")
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

    from ipm.runtime import configure_threads, machine_info

    configure_threads(args.threads)
    from ipm.generators import get_generator
    from ipm.io import load_mesh, load_views
    from ipm.methods.ga import collect_generator_statistics, problem_objective
    from ipm.methods.ga_options import get_options
    from ipm.optim.ga_settings import get_settings
    from ipm.optim.ga_statistics import GeneStatistics
    from ipm.cases import load_case
    from ipm.synth import write_reference

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    views_path = _views(args)
    generator = load_case(args.case)["generator"]
    ref_path = out / "reference" / "reference.ply"
    if not ref_path.exists():
        write_reference(args.case, ref_path.parent)
    reference = load_mesh(ref_path)
    settings = get_settings(args.profile)
    options = get_options(args.profile)
    objective = problem_objective(load_views(views_path), get_generator(generator), options)
    stats_cost = 2 * settings.stats_samples
    dirs = []
    for seed in args.seeds:
        stats_path = Path(args.stats) if args.stats else out / f"seed{seed}" / f"stats_{generator}.json"
        if not stats_path.exists():
            collect_generator_statistics(generator, stats_path, profile=args.profile, seed=seed, progress=PROGRESS)
        stats = GeneStatistics.load(stats_path)
        stats.check(objective.genome.spec)
        dirs.append(run_seed(objective, settings, stats, stats_path, stats_cost, reference, options, args, seed,
                             out / f"seed{seed}"))
    print(json.dumps(aggregate(dirs, out), indent=1))


def run_seed(objective, settings, stats, stats_path, stats_cost, reference, options, args, seed, out) -> Path:
    """One seed of every algorithm: the GA with ``args.budget`` evaluations after its statistics,
    the peers with the two together; writes ``out/summary.json``, ``curves.csv``, ``curves.png``."""
    import pandas as pd

    from ipm.io import shown_path, write_json

    out.mkdir(parents=True, exist_ok=True)
    summary = {"case": args.case, "profile": args.profile, "budget": args.budget + stats_cost,
               "ga_search_evaluations": args.budget, "statistics_evaluations": stats_cost, "seed": seed,
               "statistics": shown_path(stats_path), "machine": machine_info(args.threads),
               "threads": args.threads, "algorithms": {}}
    curves = {}
    for name in args.algorithms:
        t0 = time.perf_counter()
        if name == "ga":
            best, losses = run_ga(objective, settings, stats, args.budget, seed)
            losses = np.concatenate([np.full(stats_cost, np.inf), losses])  # the statistics find no fit
        elif name == "random":
            best, losses = run_random(objective, args.budget + stats_cost, seed)
        else:
            best, losses = run_cma(objective, args.budget + stats_cost, seed)
        seconds = time.perf_counter() - t0
        curves[name] = np.minimum.accumulate(losses)
        summary["algorithms"][name] = {**describe(objective, best, reference, options), "seconds": seconds,
                                       "evaluations": int(len(losses))}
        print(f"seed {seed} {name}: {summary['algorithms'][name]}", flush=True)
    algs = summary["algorithms"]
    if "ga" in algs:
        summary["ga_over_peer"] = {
            peer: {"tsim": algs["ga"]["tsim"] / max(algs[peer]["tsim"], 1e-12),
                   "similarity": (1 - algs["ga"]["loss"]) / max(1 - algs[peer]["loss"], 1e-12),
                   "iou64": algs["ga"]["iou64"] / max(algs[peer]["iou64"], 1e-12)}
            for peer in algs if peer != "ga"}
    rows = [(name, i + 1, float(v)) for name, c in curves.items() for i, v in enumerate(c) if np.isfinite(v)]
    pd.DataFrame(rows, columns=["algorithm", "evaluations", "best_loss"]).to_csv(out / "curves.csv", index=False)
    write_json(out / "summary.json", summary)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, c in curves.items():
        ax.plot(np.arange(1, len(c) + 1), c, label=f"{name} (64-view IoU {algs[name]['iou64']:.3f})")
    ax.axvline(stats_cost, color="grey", lw=0.8, ls=":", label="GA statistics end")
    ax.set_xlabel("evaluations (GA: statistics, then search)")
    ax.set_ylabel("best objective loss (1 - similarity)")
    ax.set_title(f"{args.case}, seed {seed}: GA vs peers, {args.budget + stats_cost} evaluations")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=120)
    plt.close(fig)
    return out

if __name__ == "__main__":
    main()
