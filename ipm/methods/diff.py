"""The differentiable path as methods: ``diff`` (cameras known), ``photo`` and ``photo_fov`` (camera withheld).

Each reads the views, fits the generator with the search loop (``ipm.search.loop``) under a profile
(``ipm.profiles``) and writes the result folder (``ipm.methods.results``).
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from ipm.capture import open_views
from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.io.views import Views
from ipm.methods import check_generator
from ipm.methods.results import write_painted
from ipm.problem import Problem
from ipm.profiles import DiffProfile, get_profile
from ipm.search.loop import reconstruct
from ipm.search.moves.camera import CameraSettings
from ipm.search.objective import Objective
from ipm.search.starts import start_for
from ipm.search.trial import scorer


def fit(views: Views, generator: str, profile: str, seed: int, progress: bool, prepared=None, **overrides):
    """The diff path on ``views``: the problem, its best ``z``, the trace and the profile (for a
    camera of unknown field of view and a ``fov_grid``, :func:`fit_fov_grid`; for an unknown camera
    and ``camera_start: learned``, from the proposed camera). ``prepared``: the learned start's
    weights, the camera-hidden variant's for an unknown camera (``ipm prepare learned`` or
    ``learned_photo``; default the shipped ones; ``ipm.search.starts.start_for``)."""
    check_generator("diff", generator)
    prof = get_profile(profile, **overrides)
    camera = prof.of(CameraSettings)
    if camera.fov_grid and views.camera is not None and not views.camera.fov_known:
        return (*fit_fov_grid(views, generator, prof, seed, progress), prof)
    if camera.camera_start == "learned" and views.camera is not None:
        from ipm.learned.propose import has_weights, propose_camera
        from ipm.photo import at_proposed_camera

        if has_weights(generator, prepared, camera_hidden=True):  # else the prior, as start_for falls back
            views = at_proposed_camera(views, *propose_camera(generator, views, prepared))
    problem = Problem.for_views(get_generator(generator), views, max_tilt=prof.loop.max_tilt)
    start = start_for(problem, views, prof.loop.start, prof.loop.learned_proposals, prepared)
    z, trace = reconstruct(problem, views, prof, seed=seed, progress=progress, start=start)
    return problem, z, trace, prof


def final_score(problem: Problem, views: Views, z: np.ndarray, prof: DiffProfile) -> float:
    """Loss of ``z`` at the last refinement resolution over fixed render seeds: fits of the same
    mask under different held cameras compared alike (:func:`fit_fov_grid`)."""
    lod = max(prof.loop.refine_lod, problem.generator.min_fit_lod)
    return scorer(Objective(problem, views, prof.loop.refine_res[-1], lod, prof.objective), (10_007, 10_008))(z)


def fit_at_fov(views: Views, generator: str, prof: DiffProfile, seed: int, progress: bool,
               fov_deg: float) -> tuple[Problem, np.ndarray, pd.DataFrame, float]:
    """One point of :func:`fit_fov_grid`: the fit of ``views`` (an unknown camera) with its field
    of view held at ``fov_deg``, and its :func:`final_score`."""
    camera = replace(views.camera, fov0=float(np.radians(fov_deg)), fov_known=True, fov_chosen=True)
    held = replace(views, fov_x=camera.fov0, camera=camera)
    problem = Problem.for_views(get_generator(generator), held, max_tilt=prof.loop.max_tilt)
    z, trace = reconstruct(problem, held, prof, seed=seed, progress=progress)
    return problem, z, trace, final_score(problem, held, z, prof)


def fit_fov_grid(views: Views, generator: str, prof: DiffProfile, seed: int,
                 progress: bool) -> tuple[Problem, np.ndarray, pd.DataFrame]:
    """An unknown field of view chosen from the profile's ``fov_grid``: a fit per value with it held
    (:func:`fit_at_fov`, the same seed each), the one of lowest score kept; its trace gets a
    ``fov grid`` row per value (the score as its loss, the fits' seconds summed)."""
    fits, grid = [], prof.of(CameraSettings).fov_grid
    for k, f in enumerate(grid):
        if progress:
            tqdm.write(f"field of view {f:g} degrees ({k + 1} of {len(grid)})")
        fits.append(fit_at_fov(views, generator, prof, seed, progress, f))
    problem, z, trace, _ = min(fits, key=lambda fit: fit[3])
    seconds = np.cumsum([float(fit[2]["seconds"].iloc[-1]) for fit in fits])
    rows = pd.DataFrame({"stage": "fov grid", "res": prof.loop.refine_res[-1], "eval": len(trace) + np.arange(len(fits)),
                         "origin": [f"fov={f:g}" for f in grid], "loss": [fit[3] for fit in fits],
                         "best": float(trace["best"].iloc[-1]), "seconds": seconds})
    return problem, z, pd.concat([trace, rows], ignore_index=True)


def write_fit(out: str | Path, problem: Problem, z: np.ndarray, trace: pd.DataFrame, prof: DiffProfile,
           info: dict, seconds: float, place: np.ndarray | None = None, views: Views | None = None) -> dict:
    """The fit's result folder (``ipm.methods.results``): its mesh at the output level of detail,
    moved first by ``place`` (4 x 4, a similarity) where given, and ``info`` with the decoded ``z``;
    where ``views`` (in the mesh's world) have colour images, the mesh painted from them
    (``ipm.texture``; its seconds in the fit's and apart as ``texture_seconds``; where they cannot
    be read, params.json's ``texture`` says why and the mesh stays unpainted)."""
    mesh = placed_mesh(problem.world_mesh(z, max(prof.loop.output_lod, problem.generator.min_fit_lod)), place)
    info = {**problem.decode(z), "final_loss": float(trace["best"].iloc[-1]), "evaluations": len(trace),
            "settings": prof.as_dict(), **start_record(trace, prof), **info}
    return write_painted(out, problem.generator, mesh, info, seconds, trace, views)


def start_record(trace: pd.DataFrame, prof: DiffProfile) -> dict:
    """params.json's ``start`` where the fit began from the learned start: the best loss of its
    memetic stage per run of it, whether the presets' stage was added (``learned_fit``), the plan
    check's input-view IoU, whether other plans were added (``plan_check``) and whose finalist was
    kept, and, where the presets' stage was added, which start the best of the memetic stage came from."""
    rows = trace[trace["stage"] == "start"]
    if rows.empty:
        return {}
    checks = [{"loss": float(r.loss), "presets_added": r.origin.endswith("presets added")}
              for r in rows.itertuples() if r.origin.startswith("learned")]
    plans = [{"input_iou": float(r.origin.split("input IoU ")[1].split(",")[0]),
              "other_plans_added": r.origin.endswith("other plans added")}
             for r in rows.itertuples() if r.origin.startswith("plan check")]
    won = [r.origin.split(": ")[1] for r in rows.itertuples() if r.origin.startswith("won")]
    kept = [r.origin.split(": ")[1] for r in rows.itertuples() if r.origin.startswith("plan finalist")]
    return {"start": {"learned_fit": prof.loop.learned_fit, "checks": checks, "plan_check": prof.loop.plan_check,
                      "plan_checks": plans, "plan_finalist": kept[0] if kept else None,
                      "won": won[0] if won else "learned"}}


def placed_mesh(mesh, place: np.ndarray | None):
    """``mesh`` moved by ``place`` (4 x 4, a similarity; None: as it is)."""
    if place is None:
        return mesh
    return replace(mesh, vertices=mesh.vertices @ place[:3, :3].T + place[:3, 3],
                   normals=mesh.normals @ (place[:3, :3] / np.cbrt(np.linalg.det(place[:3, :3]))).T)


def run_diff(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
             seed: int = 0, progress: bool = True, n_input_views: int | None = None, prepared=None,
             **overrides) -> dict:
    """``ipm reconstruct --method diff``: write mesh.ply, mesh.glb, params.json, trace.csv, timing.json."""
    t0 = time.perf_counter()
    views = open_views(views_path).first(n_input_views)
    problem, z, trace, prof = fit(views, generator, profile, seed, progress, prepared=prepared, **overrides)
    info = {"method": "diff", "profile": profile, "seed": seed, **views.input_frame()}
    return write_fit(out, problem, z, trace, prof, info, time.perf_counter() - t0, views=views)


def run_photo(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
              seed: int = 0, progress: bool = True, n_input_views: int | None = 1, fov_given: bool = False,
              prepared=None, segment_image: bool = False, **overrides) -> dict:
    """The benchmark's camera-withheld row: the first view's mask alone, without its camera or field
    of view (with ``fov_given``, with its field of view), goes to the diff path (``ipm.photo``);
    only afterwards, to score it, the result is placed in the views' world by taking the estimated
    camera to the given one's position and heading, keeping the ground and the vertical
    (:func:`ipm.photo.registration`), and the camera's errors are recorded in params.json. With
    ``segment_image``, the mask the fit sees is the first image segmented (:func:`segmented`)."""
    from ipm.photo import scored_placement, withheld

    t0 = time.perf_counter()
    given = open_views(views_path).first(1)
    seen, extra = segmented(given) if segment_image else (given, {})
    problem, z, trace, prof = fit(withheld(seen, fov_given), generator, profile, seed, progress, prepared,
                                  **overrides)
    place, placed = scored_placement(problem, z, given)
    method = "photo_image" if segment_image else "photo_fov" if fov_given else "photo"
    info = {"method": method, "profile": profile, "seed": seed, **placed, **extra}
    return write_fit(out, problem, z, trace, prof, info, time.perf_counter() - t0, place=place)


def segmented(given: Views) -> tuple[Views, dict]:
    """``given`` (one view) with its mask replaced by its image segmented
    (``ipm.segment.mask_from_photo``), and what params.json records of it: the segmentation's IoU
    with the mask it replaced (``segmentation.mask_iou``), which the fit never sees."""
    from PIL import Image

    from ipm.errors import UserError
    from ipm.metrics.silhouette import view_ious
    from ipm.segment import mask_from_photo

    path = given.root / given.frames[0]["file_path"]
    with Image.open(path) as img:
        rgb = np.asarray(img.convert("RGB"))
    if rgb.shape[:2] != given.masks[0].shape:
        raise UserError(f"{path} is {rgb.shape[1]}x{rgb.shape[0]} px, its views {given.width}x{given.height}")
    if given.lens is not None:  # the photo its pinhole twin sees, as the masks were read
        rgb = given.lens.resample(rgb[None])[0]
    mask = mask_from_photo(rgb)
    mask_iou = float(view_ious(given.masks[:1] > 0.5, mask[None] > 0.5)[0])
    return replace(given, masks=mask[None]), {"segmentation": {"mask_iou": round(mask_iou, 4)}}


def run_photo_image(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
                    seed: int = 0, progress: bool = True, n_input_views: int | None = 1, prepared=None,
                    **overrides) -> dict:
    """The camera-withheld row from the photo alone: the first view's image segmented in place of its
    mask, which only scores the segmentation (:func:`run_photo`, ``segment_image``)."""
    return run_photo(views_path, out, generator, profile, seed, progress, n_input_views, prepared=prepared,
                     segment_image=True, **overrides)


def run_photo_fov(views_path: str | Path, out: str | Path, generator: str = "dishes", profile: str = "default",
                  seed: int = 0, progress: bool = True, n_input_views: int | None = 1, prepared=None,
                  **overrides) -> dict:
    """The camera-withheld row with the field of view given, as a photo's Exif gives it: pitch,
    roll, pose and shape estimated (:func:`run_photo`)."""
    return run_photo(views_path, out, generator, profile, seed, progress, n_input_views, fov_given=True,
                     prepared=prepared, **overrides)
