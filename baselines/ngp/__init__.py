"""Instant-NGP-style baseline after Mueller et al. 2022, "Instant neural graphics primitives with a
multiresolution hash encoding".

A radiance field (hash encoding, ``encoding.py``; a density MLP with a truncated-exp activation
and a colour MLP) is fitted to the known views by volume rendering random batches of pixel rays
(``render.py``): samples only in the cells of an occupancy grid that is refreshed every few
steps from the density at jittered cell points (decaying maximum, threshold), Adam (optax). The
loss is the squared error of each ray's colour composited over the views' background colour
(the median colour of the background pixels: the synthetic views' constant environment) plus
the squared error of its opacity against the mask, so the masks act as alpha. Views without
readable RGB images are fitted on the masks alone. The mesh: marching cubes of the density on a
grid over the object box at ``level``, less its connected components whose volume is under
``keep`` of the largest one's (the floaters, and bubbles of low density inside the object); world
frame.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from PIL import Image

from baselines.common import begin, extract_surface, write_result
from baselines.ngp.encoding import HashGrid


@dataclass(frozen=True)
class Profile:
    """Settings of one run; lengths and densities are in units of the box's longest side ``L``."""

    grid: HashGrid = field(default_factory=HashGrid)
    hidden: int = 64
    """Width of the one hidden layer of the density and of the colour MLP."""
    view_dependent: bool = False
    """Whether the colour MLP also takes the view direction (the references are diffuse)."""
    steps: int = 350
    rays: int = 4096
    """Rays per batch, drawn uniformly (seeded) from all pixels whose ray crosses the box."""
    samples: int = 65536
    """Network samples per batch, spread over the batch's occupied candidates."""
    candidates: int = 512
    """Candidate steps over the box diagonal: the finest sample spacing is ``min_ratio`` of one."""
    min_ratio: float = 0.5
    occupancy: int = 64
    """Occupancy cells per axis over the box."""
    occupancy_every: int = 16
    """Steps between occupancy updates (every cell's density at a fresh jittered point)."""
    occupancy_warmup: int = 64
    """Steps during which every cell counts as occupied (the density is still noise)."""
    occupancy_decay: float = 0.95
    occupancy_tau: float = 0.01
    """A cell is occupied while its density gives more than this optical depth over one candidate
    step (or exceeds the grid's mean density, whichever is lower)."""
    lr: float = 1e-2
    """Adam's learning rate (the paper's; betas 0.9, 0.99, eps 1e-15), cosine-decayed to a tenth."""
    mask_weight: float = 1.0
    """Weight of the opacity-against-mask term next to the colour term."""
    mesh_grid: int = 128
    """Mesh grid cells along the box's longest side."""
    level: float = 50.0
    """Density (1 / L) of the extracted surface."""
    keep: float = 0.05
    """Mesh components whose volume is under this share of the largest one's are dropped."""


PROFILES = {
    "smoke": Profile(grid=HashGrid(levels=8, log2_table=14, n_min=8, n_max=128), hidden=32, steps=80,
                     rays=1024, samples=16384, candidates=128, occupancy=32, occupancy_every=8,
                     occupancy_warmup=16, mesh_grid=48, level=10.0),
    "default": Profile(),
    "paper": Profile(grid=HashGrid(levels=16, log2_table=19, n_min=16, n_max=2048), steps=2000, rays=8192,
                     samples=131072, candidates=1024, occupancy=128, mesh_grid=256),
}
"""Per-profile settings. ``default``: the paper's encoding shape (16 levels, F = 2, 16 to 512 over
the box, 2^16 entries a level) and 64-wide MLPs, 350 steps of 4096 rays (500 until the dev check
in ``docs/decisions.md``, "Instant-NGP-style steps": 0.61 x the time, no dev case 0.005 lower):
a 16-view job of 256 px in 2-3 minutes on one core of the faster kind. ``paper``: the
paper's NeRF table (2^19 entries, 16 to 2048), a 128^3 occupancy grid, twice the rays and
samples and 2000 steps (the paper's GPU runs take many more, far past a CPU's budget): about
0.6 s a step on 2 cores, some 22 minutes for 16 views (timed over 40 steps);
``smoke`` runs in seconds. ``level`` 50 scored best of 10, 25, 50, 100 and 200 on cup_1, cup_2
and building_1 (16 views); the smoke run's densities stay lower (its 99th percentile about 50),
and 10 scored best of 2, 5, 10, 20 and 50 on cup_1 (3 views of 48 px)."""


def read_rgb(views) -> np.ndarray | None:
    """The views' RGB images (n, h, w, 3) in [0, 1] as stored (sRGB), resampled like the masks
    for a non-pinhole capture; None when a frame has no readable image of the views' size."""
    images = []
    for frame in views.frames:
        name = frame.get("file_path") if isinstance(frame, dict) else None
        if not name:
            return None
        path = views.root / str(name)
        if not path.is_file() and not path.suffix:
            path = path.with_suffix(".png")
        try:
            img = np.asarray(Image.open(path).convert("RGB"), np.float32) / 255.0
        except (OSError, ValueError):
            return None
        if img.shape[:2] != (views.height, views.width):
            return None
        images.append(img)
    rgb = np.stack(images)
    return rgb if views.lens is None else np.clip(views.lens.resample(rgb), 0.0, 1.0)


def background_colour(rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """Median colour of the background pixels of all views (3,)."""
    return np.median(rgb[masks < 0.5], axis=0).astype(np.float32)


def training_data(views, lo: np.ndarray, hi: np.ndarray) -> tuple[dict, np.ndarray | None]:
    """Every ray that crosses the box with its target colour and mask (numpy), and the background
    colour (None when the views have no RGB images: masks only)."""
    from baselines.ngp.render import unit_rays

    rays = unit_rays(views.c2w, views.fov_x, views.width, views.height, lo, hi)
    data = {"origin": rays.origin, "direction": rays.direction, "t0": rays.t0, "t1": rays.t1,
            "mask": views.masks.reshape(-1)[rays.pixel].astype(np.float32)}
    rgb = read_rgb(views)
    if rgb is None:
        return data, None
    data["rgb"] = rgb.reshape(-1, 3)[rays.pixel]
    return data, background_colour(rgb, views.masks)


def drop_floaters(verts: np.ndarray, faces: np.ndarray, keep: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The mesh without its connected components whose |volume| is under ``keep`` times the
    largest one's, and how many were dropped."""
    import trimesh

    parts = trimesh.Trimesh(verts, faces, process=False).split(only_watertight=False)
    if len(parts) <= 1:
        return verts, faces, 0
    volume = np.abs([p.volume for p in parts])
    big = [p for p, v in zip(parts, volume) if v >= keep * volume.max()]
    mesh = trimesh.util.concatenate(big)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces), len(parts) - len(big)


def run_ngp(views_path, out, profile: str = "default", seed: int = 0, progress: bool = True,
            n_input_views: int | None = None, **_) -> dict:
    """``ipm baseline ngp``: OUT/mesh.ply (world frame), timing.json, info.json."""
    prof, t0, cpu0, views, lo, hi = begin(PROFILES, profile, views_path, n_input_views)
    from baselines.ngp import train

    data, bg = training_data(views, lo, hi)
    t_data = time.perf_counter() - t0
    params, bits, stats = train.fit(data, bg, (hi - lo) / float((hi - lo).max()), prof, seed, progress)
    t_mesh = time.perf_counter()
    sigma = train.density_grid(params, lo, hi, prof)
    verts, faces = extract_surface(sigma, lo, hi, prof.level, inside_positive=True)
    verts, faces, dropped = drop_floaters(verts, faces, prof.keep)
    info = {"method": "ngp", "views": len(views), "profile": profile, "seed": seed, "settings": asdict(prof),
            "resolutions": prof.grid.resolutions().tolist(), "dense_levels": int(prof.grid.dense().sum()),
            "box": [lo.tolist(), hi.tolist()], "rays": int(len(data["t0"])), "colour": bg is not None,
            "background": None if bg is None else bg.tolist(), "mesh_cells": list(sigma.shape),
            "components_dropped": dropped, "data_seconds": t_data,
            "mesh_seconds": time.perf_counter() - t_mesh, **stats}
    info["cpu_seconds"] = time.process_time() - cpu0
    extra = {FIELD: lambda path: save_field(path, params, bits)} if bg is not None else None
    return write_result(out, verts, faces, t0, info, extra)


FIELD = "field.npz"
"""A run's fitted field (with colour): the encoding's table, the MLPs' weights and the last
occupancy bits, for rendering it at other views (:func:`render_result`)."""


def save_field(path, params, bits: np.ndarray) -> None:
    """The field's parameters (leaves in ``jax.tree_util`` order) and occupancy bits as ``path``."""
    import jax

    leaves = jax.tree_util.tree_leaves(params)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, bits=np.asarray(bits), **{f"leaf_{i:03d}": np.asarray(x) for i, x in enumerate(leaves)})


def render_result(run, views) -> np.ndarray:
    """A run's radiance field (its folder's field.npz and info.json) volume-rendered at every camera
    of ``views`` (``ipm.io.views.Views``) over its background colour, as linear RGB (n, H, W, 3):
    its appearance, as the workflow scores it (``ipm.metrics.texture``)."""
    import json
    from pathlib import Path

    import jax

    from baselines.ngp import encoding as enc
    from baselines.ngp import train
    from baselines.ngp.render import unit_rays
    from ipm.errors import UserError
    from ipm.io.views import linear_from_srgb

    run = Path(run)
    if not (run / FIELD).is_file():
        raise UserError(f"{run}: no {FIELD} (a run on views without colour has no appearance)")
    info = json.loads((run / "info.json").read_text())
    prof = PROFILES[info["profile"]]
    with np.load(run / FIELD) as saved:
        leaves = [saved[f"leaf_{i:03d}"] for i in range(len(saved.files) - 1)]
        bits = saved["bits"]
    shape = enc.init_field(prof.grid, prof.hidden, jax.random.PRNGKey(0), prof.view_dependent)
    params = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(shape), leaves)
    lo, hi = (np.asarray(b, np.float64) for b in info["box"])
    rays = unit_rays(views.c2w, views.fov_x, views.width, views.height, lo, hi)
    srgb = train.render_images(params, bits, (hi - lo) / float((hi - lo).max()), rays,
                               np.asarray(info["background"], np.float32), (len(views), views.height, views.width),
                               prof, info["seed"])
    return linear_from_srgb(np.clip(srgb, 0.0, 1.0).astype(np.float64))
