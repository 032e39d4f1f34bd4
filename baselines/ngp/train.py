"""Fitting the field to the views' rays (Adam, occupancy updates) and reading its density back on
a grid for the mesh."""
from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm import tqdm

from baselines.ngp import encoding as enc
from baselines.ngp import render


def candidate_step(ext, prof) -> float:
    """Candidate spacing ``dt`` (units of L): ``prof.candidates`` steps over the box diagonal."""
    return float(np.linalg.norm(ext)) / prof.candidates


def render_rays(params, bits, ext, batch: dict, key, prof):
    """Opacity (R,) and colour (R, 3) of a batch of rays, the number of samples used and their spacing."""
    points, ray, delta = render.place_samples(
        bits, ext, prof.occupancy, batch["origin"], batch["direction"], batch["t0"], batch["t1"], key,
        candidate_step(ext, prof), prof.candidates, prof.samples, prof.min_ratio)
    sigma, geo = enc.density(prof.grid, params, points)
    n = batch["t0"].shape[0]
    direction = batch["direction"][jnp.minimum(ray, n - 1)] if prof.view_dependent else None
    rgb = enc.radiance(params, geo, direction)
    alpha, colour, _ = render.composite(sigma, rgb, ray, delta, n)
    return alpha, colour, (ray < n).sum(), delta


def loss(params, bits, ext, batch: dict, key, bg, prof):
    """Squared colour error of the composite over ``bg`` (None: left out) plus ``mask_weight``
    times the squared opacity error against the mask; aux: (colour term, mask term, samples used,
    sample spacing)."""
    alpha, colour, used, delta = render_rays(params, bits, ext, batch, key, prof)
    mask_term = jnp.mean((alpha - batch["mask"]) ** 2)
    if bg is None:
        colour_term = jnp.float32(0.0)
    else:
        colour_term = jnp.mean((colour + (1.0 - alpha)[:, None] * bg - batch["rgb"]) ** 2)
    return colour_term + prof.mask_weight * mask_term, (colour_term, mask_term, used, delta)


def optimiser(prof) -> optax.GradientTransformation:
    """Adam with the paper's betas and epsilon, the rate cosine-decayed to a tenth."""
    schedule = optax.cosine_decay_schedule(prof.lr, max(1, prof.steps), alpha=0.1)
    return optax.adam(schedule, b1=0.9, b2=0.99, eps=1e-15)


@functools.lru_cache(maxsize=8)
def make_step(prof, ext: tuple, colour: bool):
    """The jitted training step ``(params, opt_state, data, bits, bg, key) -> (params, opt_state,
    loss, aux)``: a seeded batch of rays, the loss, its gradient and Adam's update."""
    opt = optimiser(prof)
    ext = np.asarray(ext, np.float32)

    def step(params, opt_state, data, bits, bg, key):
        kb, kr = jax.random.split(key)
        idx = jax.random.randint(kb, (prof.rays,), 0, data["t0"].shape[0])
        batch = {k: v[idx] for k, v in data.items()}
        (value, aux), grads = jax.value_and_grad(loss, has_aux=True)(
            params, bits, ext, batch, kr, bg if colour else None, prof)
        updates, opt_state = opt.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, value, aux

    return jax.jit(step, donate_argnums=(0, 1))


def densities(prof, params, points, chunk: int = 1 << 15):
    """Density at ``points`` (n, 3) in the unit frame, ``chunk`` points at a time (n a multiple of it)."""
    parts = points.reshape(-1, chunk, 3)
    return jax.lax.map(lambda p: enc.density(prof.grid, params, p)[0], parts).reshape(-1)


@functools.lru_cache(maxsize=8)
def make_occupancy_update(prof, ext: tuple):
    """The jitted occupancy update ``(params, values, key) -> (values, bits)``: every cell's density
    at a fresh jittered point, folded in by ``render.update_occupancy``."""
    n = prof.occupancy
    ext = np.asarray(ext, np.float32)
    threshold = prof.occupancy_tau / candidate_step(ext, prof)
    chunk = min(1 << 15, n ** 3)

    def update(params, values, key):
        points = render.cell_points(ext, n, jax.random.uniform(key, (n ** 3, 3)))
        return render.update_occupancy(values, densities(prof, params, points, chunk), prof.occupancy_decay,
                                       threshold)

    return jax.jit(update)


def fit(data: dict, bg, ext: np.ndarray, prof, seed: int, progress: bool = False):
    """The fitted field's parameters, its last occupancy bits and the run's statistics (losses, the
    final ones averaged over the last twentieth of the steps; occupancy, sample spacing, times)."""
    t0 = time.perf_counter()
    key = jax.random.PRNGKey(seed)
    key, kinit = jax.random.split(key)
    params = enc.init_field(prof.grid, prof.hidden, kinit, prof.view_dependent)
    opt_state = optimiser(prof).init(params)
    colour = bg is not None
    arrays = {k: jnp.asarray(v) for k, v in data.items()}
    bg = jnp.asarray(bg if colour else np.zeros(3, np.float32))
    ext_t = tuple(float(e) for e in ext)
    step = make_step(prof, ext_t, colour)
    refresh = make_occupancy_update(prof, ext_t)
    values = jnp.zeros(prof.occupancy ** 3, jnp.float32)
    every = jnp.ones(prof.occupancy ** 3, bool)
    bits = every
    trace, occupied = [], []
    bar = tqdm(total=prof.steps, desc="ngp", disable=not progress, leave=False)
    t_first = None
    for it in range(prof.steps):
        key, ko, ks = jax.random.split(key, 3)
        if it % prof.occupancy_every == 0:
            values, bits = refresh(params, values, ko)
            if it < prof.occupancy_warmup:
                bits = every
            occupied.append(bits.mean())
        params, opt_state, value, aux = step(params, opt_state, arrays, bits, bg, ks)
        trace.append((value, *aux))
        if t_first is None:
            value.block_until_ready()
            t_first = time.perf_counter() - t0
        bar.update(1)
    bar.close()
    rows = np.array([[float(x) for x in row] for row in trace])
    tail = rows[-max(1, len(rows) // 20):]
    stats = {"steps": prof.steps, "final_loss": float(tail[:, 0].mean()),
             "final_colour_loss": float(tail[:, 1].mean()), "final_mask_loss": float(tail[:, 2].mean()),
             "first_loss": float(rows[0, 0]), "samples_used_mean": float(rows[:, 3].mean()),
             "sample_spacing_first": float(rows[0, 4]), "sample_spacing_final": float(tail[:, 4].mean()),
             "occupied_share": [round(float(x), 4) for x in occupied[:: max(1, len(occupied) // 16)]],
             "occupied_share_final": float(occupied[-1]) if occupied else 1.0,
             "loss_trace": [round(float(x), 6) for x in rows[:: max(1, len(rows) // 50), 0]],
             "compile_and_first_step_seconds": t_first, "train_seconds": time.perf_counter() - t0}
    return params, np.asarray(bits), stats


def density_grid(params, lo: np.ndarray, hi: np.ndarray, prof, chunk: int = 1 << 15) -> np.ndarray:
    """The density (1 / L) at the cell centres of a grid over [lo, hi] with ``prof.mesh_grid``
    cells along the longest side (near-cubic cells)."""
    from baselines.diffsdf.field import cell_centres, grid_shape

    scale = float((hi - lo).max())
    shape = grid_shape(lo, hi, prof.mesh_grid)
    axes = [(c - lo[k]) / scale for k, c in enumerate(cell_centres(lo, hi, shape))]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    n = len(points)
    padded = np.concatenate([points, np.zeros((-n % chunk, 3), np.float32)])
    run = jax.jit(functools.partial(densities, prof, chunk=chunk))
    return np.asarray(run(params, jnp.asarray(padded)))[:n].reshape(shape)


@functools.lru_cache(maxsize=8)
def make_render(prof, ext: tuple):
    """The jitted ``(params, bits, batch, key) -> (alpha (R,), colour (R, 3))`` of a batch of
    ``prof.rays`` rays, sampled as in training."""
    ext = np.asarray(ext, np.float32)

    def run(params, bits, batch, key):
        alpha, colour, _, _ = render_rays(params, bits, ext, batch, key, prof)
        return alpha, colour

    return jax.jit(run)


def render_images(params, bits, ext: np.ndarray, rays, bg: np.ndarray, shape: tuple, prof, seed: int = 0):
    """The field's colour composited over ``bg`` at every pixel of ``shape`` (views, height, width)
    whose ray (``render.UnitRays``) crosses the box, ``bg`` elsewhere: (views, height, width, 3)
    in the training images' values (sRGB), ``prof.rays`` rays a batch."""
    run = make_render(prof, tuple(float(e) for e in ext))
    n, size = len(rays.t0), prof.rays
    pad = -n % size
    arrays = {k: np.concatenate([getattr(rays, k), np.repeat(getattr(rays, k)[:1], pad, 0)])
              for k in ("origin", "direction", "t0", "t1")}
    key = jax.random.PRNGKey(seed)
    out = np.zeros((n + pad, 3), np.float32)
    for start in range(0, n + pad, size):
        key, kr = jax.random.split(key)
        alpha, colour = run(params, bits, {k: v[start:start + size] for k, v in arrays.items()}, kr)
        out[start:start + size] = np.asarray(colour) + (1.0 - np.asarray(alpha))[:, None] * bg
    images = np.tile(np.asarray(bg, np.float32), (int(np.prod(shape)), 1))
    images[rays.pixel] = out[:n]
    return images.reshape(*shape, 3)
