"""``learned``: the regressor's proposal alone, no search (``ipm.learned``): the benchmark's
learned single-view row, trained on the same generators as ours; ``learned_photo``: the same with
the camera withheld, its pitch and field of view proposed by the camera-hidden variant."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from ipm.capture import open_views
from ipm.generators import get_generator
from ipm.methods import check_generator
from ipm.methods.results import write_result
from ipm.problem import Problem
from ipm.profiles import get_profile


def run_learned(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
                seed: int = 0, progress: bool = True, n_input_views: int | None = 1,
                prepared: str | Path | None = None) -> dict:
    """``ipm reconstruct --method learned``: the most probable proposal for the first view, written
    as the diff path writes its fit (mesh.ply, mesh.glb, params.json, trace.csv, timing.json);
    weights from ``prepared`` (``ipm prepare --method learned``) or the shipped ones."""
    from ipm.learned.propose import propose, weights_path

    t0 = time.perf_counter()
    check_generator("learned", generator)
    views = open_views(views_path).first(n_input_views)
    problem = Problem.for_views(get_generator(generator), views)
    z = propose(problem, views, k=1, prepared=prepared)[0]
    info = {"method": "learned", "weights": Path(weights_path(generator, prepared)).name, **views.input_frame()}
    return _write(out, problem, z, views.width, profile, seed, info, t0)


def run_learned_photo(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
                      seed: int = 0, progress: bool = True, n_input_views: int | None = 1,
                      prepared: str | Path | None = None) -> dict:
    """``ipm reconstruct --method learned_photo``: the camera-hidden regressor's proposal alone for
    the first view's mask, its pitch and field of view proposed too (``ipm.learned.propose``). A
    photo (``--image``) keeps its own world and a field of view it was given; posed views have
    their camera withheld and the result is placed in their world to be scored, as the
    camera-withheld diff rows are (``ipm.methods.diff.run_photo``)."""
    from ipm.learned.propose import propose, propose_camera, weights_path
    from ipm.photo import at_proposed_camera, scored_placement, withheld

    t0 = time.perf_counter()
    check_generator("learned_photo", generator)
    given = open_views(views_path).first(1)
    photo = given if given.camera is not None else withheld(given)
    photo = at_proposed_camera(photo, *propose_camera(generator, photo, prepared))
    problem = Problem.for_views(get_generator(generator), photo)
    z = propose(problem, photo, k=1, prepared=prepared)[0]
    info = {"method": "learned_photo", "weights": Path(weights_path(generator, prepared, camera_hidden=True)).name}
    place = None
    if given.camera is None:
        place, placed = scored_placement(problem, z, given)
        info.update(placed)
    return _write(out, problem, z, photo.width, profile, seed, info, t0, place)


def _write(out, problem: Problem, z: np.ndarray, width: int, profile: str, seed: int, info: dict, t0: float,
           place: np.ndarray | None = None) -> dict:
    """A proposal's result folder (``ipm.methods.results``): its mesh at the profile's output level
    of detail, moved by ``place`` where given, a one-row trace, ``info`` after the decoded ``z``."""
    from ipm.methods.diff import placed_mesh

    gen = problem.generator
    mesh = placed_mesh(problem.world_mesh(z, max(get_profile(profile).loop.output_lod, gen.min_fit_lod)), place)
    seconds = time.perf_counter() - t0
    trace = pd.DataFrame({"stage": ["proposal"], "res": [width], "eval": [0], "origin": ["learned"],
                          "loss": [np.nan], "best": [np.nan], "seconds": [seconds]})
    info = {**problem.decode(z), "profile": profile, "seed": seed, **info}
    return write_result(out, mesh, info, {"seconds": seconds}, trace)
