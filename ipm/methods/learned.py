"""``learned``: the regressor's proposal alone, no search (``ipm.learned``): the benchmark's
learned single-view row, trained on the same generators as ours."""
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
    gen = get_generator(generator)
    problem = Problem.for_views(gen, views)
    z = propose(problem, views, k=1, prepared=prepared)[0]
    mesh = problem.world_mesh(z, max(get_profile(profile).loop.output_lod, gen.min_fit_lod))
    seconds = time.perf_counter() - t0
    trace = pd.DataFrame({"stage": ["proposal"], "res": [views.width], "eval": [0], "origin": ["learned"],
                          "loss": [np.nan], "best": [np.nan], "seconds": [seconds]})
    info = {**problem.decode(z), "method": "learned", "profile": profile, "seed": seed,
            "weights": Path(weights_path(generator, prepared)).name, **views.input_frame()}
    return write_result(out, mesh, info, {"seconds": seconds}, trace)
