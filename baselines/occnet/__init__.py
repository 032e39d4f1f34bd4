"""Occupancy-network baseline after Mescheder et al. 2019, "Occupancy Networks: learning 3D
reconstruction in function space": a learned shape prior from one view, without the program.

A network (``network.py``: the regressor's image encoder, a latent code with the camera numbers,
an MLP decoder over Fourier-encoded points) maps the view's mask (and a building's window mask
where given) and camera, encoded as the learned regressor reads them (``ipm.learned.data``), to an
occupancy field in the frame the view fixes (``data.py``: the mask's anchor, turned by the
camera's azimuth). It is trained on the same generator samples as the regressor (``train.py``),
so beside the procedural rows it shows what knowing the program buys over a learned prior of the
same data. The mesh: marching cubes of the occupancy probability on a grid over the local box at
``level``, less the components under ``keep`` of the largest one's volume, mapped to the world.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from baselines.occnet.train import PROFILES, OccnetSettings, fit, occnet_settings, prepare, summary

__all__ = ["PROFILES", "OccnetSettings", "fit", "occnet_settings", "prepare", "run_occnet", "local_grid"]


def local_grid(box: np.ndarray, cells: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Cell centres (n, 3) of a grid over ``box`` (2, 3) with ``cells`` cells along its longest
    side (about cubic cells), and the grid's shape."""
    box = np.asarray(box, float)
    extent = box[1] - box[0]
    shape = tuple(int(max(2, round(cells * e / extent.max()))) for e in extent)
    axes = [box[0, k] + (np.arange(shape[k]) + 0.5) * extent[k] / shape[k] for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3).astype(np.float32), shape


def run_occnet(views_path, out, generator: str | None = None, profile: str = "default", seed: int = 0,
               progress: bool = True, n_input_views: int | None = 1, prepared: str | Path | None = None,
               **overrides) -> dict:
    """``ipm baseline occnet --generator G``: OUT/mesh.ply (world frame), timing.json, info.json
    from the first view; weights from ``prepared`` (``ipm prepare occnet``), else trained in the
    run with the profile's budget."""
    from baselines.common import extract_surface, input_views, write_failure, write_result
    from baselines.ngp import drop_floaters
    from baselines.occnet.data import to_world, view_frame
    from baselines.occnet.network import field, load
    from ipm.errors import UserError
    from ipm.generators import get_generator
    from ipm.learned.data import encode_view

    t0, cpu0 = time.perf_counter(), time.process_time()
    if generator is None:
        raise UserError("occnet learns from a generator's samples: name the class (--generator dishes, buildings)")
    gen = get_generator(generator)
    settings = occnet_settings(profile, **overrides)
    views = input_views(views_path, 1 if n_input_views is None else min(n_input_views, 1), minimum=1)
    if views.camera is not None:
        raise UserError("occnet needs the view's camera (a posed view in transforms.json)")
    mask, c2w = views.masks[0], views.c2w[0]
    if not np.any(mask > 0.5):
        raise UserError("the input mask is empty: no object to reconstruct")
    if prepared is not None:
        model, meta = load(prepared, expect_generator=gen.name)
        weights = Path(prepared).name
    else:
        model, meta = fit(gen, settings, seed, progress)
        weights = "trained in the run"
    image, cond = encode_view(mask, c2w, views.fov_x, _class_mask(gen, views), meta["in_channels"])
    anchor_t, anchor_s, azimuth = view_frame(mask, c2w, views.fov_x)
    t_mesh = time.perf_counter()
    box = np.asarray(meta["box"], float)
    points, shape = local_grid(box, settings.mesh_grid)
    probability = field(model, image, cond, points).reshape(shape)
    info = {"method": "occnet", "generator": gen.name, "views": 1, "profile": profile, "seed": seed,
            "settings": {k: getattr(settings, k) for k in ("mesh_grid", "level", "keep")},
            "weights": weights, "training": {"seed": meta.get("seed"), **summary(meta)},
            "anchor": {"t": anchor_t.tolist(), "s": anchor_s, "azimuth": azimuth}, "mesh_cells": list(shape),
            "occupied_share": float(np.mean(probability > settings.level))}
    try:
        verts, faces = extract_surface(probability, box[0], box[1], settings.level, inside_positive=True)
    except UserError as exc:
        info["cpu_seconds"] = time.process_time() - cpu0
        return write_failure(out, t0, info, str(exc))
    verts, faces, dropped = drop_floaters(verts, faces, settings.keep)
    info.update(components_dropped=dropped, mesh_seconds=time.perf_counter() - t_mesh,
                cpu_seconds=time.process_time() - cpu0)
    return write_result(out, to_world(verts, anchor_t, anchor_s, azimuth), faces, t0, info)


def _class_mask(gen, views) -> np.ndarray | None:
    """The first view's mask of the generator's class (a building's windows), None where the views
    have none (``ipm.search.objective.class_masks``)."""
    from ipm.search.objective import class_masks

    found = class_masks(gen, views)
    return None if found is None else found[0][0]
