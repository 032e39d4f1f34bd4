"""The genetic path (paper, "Non-differentiable Case"): the tree of elementary GAs over generator
parameters and pose, fitted to one view (or a few) by ray-cast impostors.

Its parts: the genome and its pose genes (``ipm.methods.ga_genome``), the objective's settings
(``ipm.methods.ga_options``), the impostors (``ipm.losses.impostors``), the loss
(``ipm.losses.tree_objective``) and the tree GA itself (``ipm.optim.ga``). This module reads the
views, runs the search and writes the result.

**Statistics** (the paper's ``V(k)``, ``P_ij``, ``Q_ij``): gathered per generator on random
genomes against a family of canonical references (each preset of the generator seen from a
near-horizontal camera with a known anchor, ``ipm.losses.tree_objective.family_objective``), so
one JSON file serves every case: :func:`collect_generator_statistics` (a cached pipeline stage),
or collected by :func:`run_ga` itself when no file is given, at ``2 * stats_samples`` evaluations
(``default``: 2000).
"""
from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ipm.capture import open_views
from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.generators.base import Generator
from ipm.io import shown_path
from ipm.io.views import Views
from ipm.losses.impostors import make_target
from ipm.losses.tree_objective import Objective, family_objective
from ipm.methods.ga_genome import Genome, anchor
from ipm.methods.ga_options import GAOptions, get_options, output_lod, uses_tree_loss
from ipm.methods.results import write_painted
from ipm.optim.ga import TreeGA
from ipm.optim.ga_settings import GASettings, get_settings
from ipm.optim.ga_statistics import GeneStatistics, collect_statistics


def generator_statistics(generator: Generator, settings: GASettings, options: GAOptions, seed: int = 0,
                         progress: bool = False) -> GeneStatistics:
    """The paper's gene statistics of ``generator``'s genome over its family of canonical
    references (``ipm.losses.tree_objective.family_objective``): ``2 * settings.stats_samples`` evaluations."""
    objective = family_objective(generator, options)
    return collect_statistics(objective.genome.spec, objective.losses, settings.stats_samples, settings.bins,
                              seed=seed, progress=progress, h=settings.stats_h,
                              good_fraction=settings.good_fraction, prior=settings.stats_prior)


def collect_generator_statistics(generator: str, out_path: str | Path, profile: str = "default", seed: int = 0,
                                 progress: bool = False, **options) -> dict:
    """Pipeline stage: gene statistics of ``generator`` for the GA path, written to ``out_path``
    (JSON, atomically; load with ``GeneStatistics.load``). Cost: ``2 * stats_samples`` of the
    profile's evaluations (``default``: 2000, 2-3 minutes for trees on one core)."""
    t0 = time.perf_counter()
    gen = get_generator(generator)
    settings = get_settings(profile)
    opts = get_options(profile, **options)
    stats = generator_statistics(gen, settings, opts, seed, progress)
    stats.save(out_path)
    return {"generator": generator, "samples": stats.n_samples, "seconds": time.perf_counter() - t0}


def _read_rgb(path: Path, width: int, height: int) -> np.ndarray:
    from PIL import Image

    if not path.is_file():
        raise UserError(f"RGB image not found: {path} (needed for labels_from_rgb without a semantic_path)")
    try:
        with Image.open(path) as im:
            rgb = np.asarray(im.convert("RGB"))
    except Exception as exc:
        raise UserError(f"cannot read RGB image {path}: {exc}") from None
    if rgb.shape[:2] != (height, width):
        raise UserError(f"RGB image {path} is {rgb.shape[1]}x{rgb.shape[0]}, expected {width}x{height}")
    return rgb


def reference_labels(views: Views, tree: bool, source: str = "auto") -> np.ndarray:
    """Per-view reference labels (n, H, W): for the tree loss the views' label images (``source``
    ``semantic``, or ``auto`` where they have them) or ``labels_from_rgb`` of the RGB inside the
    mask (``rgb``); for other generators the mask as label 1."""
    if not tree:
        return (views.masks > 0.5).astype(np.uint8)
    if source == "semantic" and views.semantics is None:
        raise UserError("labels: semantic, but the views have no label images (semantic_path)")
    if source != "rgb" and views.semantics is not None:
        return views.semantics
    from ipm.io.semantic import labels_from_rgb

    out = []
    for fr, mask in zip(views.frames, views.masks):
        if "file_path" not in fr:
            raise UserError("a frame has neither semantic_path nor file_path: no tree labels")
        rgb = _read_rgb(views.root / fr["file_path"], views.width, views.height)
        rgb = rgb if views.lens is None else views.lens.resample(rgb[None])[0]  # as the masks were
        out.append(labels_from_rgb(rgb, mask > 0.5))
    return np.stack(out)


def problem_objective(views: Views, generator: Generator, options: GAOptions) -> Objective:
    """The objective of a reconstruction: the genome anchored by the first view, one impostor
    target per view (checks the inputs before any search)."""
    genome = Genome(generator, *anchor(views, generator.plant), views.c2w[0])
    refs = reference_labels(views, uses_tree_loss(generator, options), options.labels)
    targets = [make_target(lab, c2w, views.fov_x, options) for lab, c2w in zip(refs, views.c2w)]
    return Objective(genome, targets, options)


def reconstruct(objective: Objective, settings: GASettings, stats: GeneStatistics | None, seed: int = 0,
                progress: bool = True):
    """The tree GA on ``objective``: best genome, its loss and the trace (one row per evaluation)."""
    ga = TreeGA(objective.genome.spec, settings, stats, seed=seed)
    return ga.minimize(objective, progress=progress)


def run_ga(views_path: str | Path | Views, out: str | Path, generator: str = "trees", profile: str = "default",
           seed: int = 0, progress: bool = True, n_input_views: int | None = None,
           prepared: str | Path | None = None, ga_settings: dict | None = None, **options) -> dict:
    """``ipm reconstruct --method ga``: write mesh.ply, mesh.glb, params.json, trace.csv, timing.json
    and, where the views have colour images, the parts' textures (``ipm.texture``).

    Parameters
    ----------
    views_path, out
        ``transforms.json`` (masks; ``semantic_path`` or RGB for trees) and the output folder.
    generator, profile, seed
        Generator name, budget profile (``ipm.optim.ga_settings.GA_PROFILES`` and
        ``ipm.methods.ga_options.PROFILE_OPTIONS``)
        and random seed (same seed, same output).
    n_input_views
        Use the first N frames (default: all); the table's row uses 1.
    prepared
        Gene statistics JSON from :func:`collect_generator_statistics` (the method's cached
        preparation stage, ``ipm prepare ga``); without it they are collected here first
        (``2 * stats_samples`` more evaluations).
    ga_settings
        Overrides of the profile's ``GASettings`` (e.g. ``{"budget": 1500}``).
    **options
        Overrides of :class:`GAOptions`; the pipeline's other keywords are ignored.
    """
    t0 = time.perf_counter()
    gen = get_generator(generator)
    settings = get_settings(profile, **(ga_settings or {}))
    opts = get_options(profile, **{k: v for k, v in options.items() if k in GAOptions.names()})
    views = open_views(views_path).first(n_input_views)
    if views.camera is not None:
        raise UserError("the view's camera is unknown: the diff path estimates it (--method diff)")
    objective = problem_objective(views, gen, opts)
    t_stats = time.perf_counter()
    if prepared is not None:
        stats = GeneStatistics.load(prepared)
        stats.check(objective.genome.spec)
        stats_source = shown_path(prepared)
    else:
        stats = generator_statistics(gen, settings, opts, seed, progress)
        stats_source = "collected"
    t_stats = time.perf_counter() - t_stats
    best, loss, trace = reconstruct(objective, settings, stats, seed, progress)
    mesh, info = objective.genome.world_mesh(best, output_lod(gen, opts))
    seconds = time.perf_counter() - t0
    info.update({"method": "ga", "profile": profile, "seed": seed, "final_loss": float(loss),
                 "evaluations": int(len(trace)), "loss": "tree" if objective.tree else "silhouette",
                 "statistics": stats_source, "settings": asdict(settings), "options": asdict(opts),
                 "parts": sorted({gen.part_names[k] for k in np.unique(mesh.labels)}), **views.input_frame()})
    return write_painted(out, gen, mesh, info, seconds, trace, views, {
        "statistics_seconds": t_stats, "search_seconds": objective.seconds,
        "seconds_per_evaluation": objective.seconds / max(objective.evaluations, 1)})
