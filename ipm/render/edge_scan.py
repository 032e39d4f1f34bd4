"""Silhouette coverage by scanlines and its edge-sampling gradient, in JAX (the kernels of
``ipm.render.edges``).

- **Coverage** (no gradient): every triangle is cut into the sample rows it crosses (a fixed
  budget of row spans, :func:`spans`); each span adds +1 / -1 to a difference image and a running
  sum along the rows counts the triangles over each sample. The samples lie on a grid whose rows
  are shifted at random per call, ``ss`` x ``ss`` per pixel, so a pixel's value is an unbiased
  estimate of its covered area (as Mitsuba's box filter with ``spp`` samples is) and neighbouring
  pixels' errors along an edge are independent. The same is done with columns for scanlines (the
  mesh transposed), and the two estimates are averaged.
- **Gradient** (edge sampling, Li et al. 2018): a pixel's covered area changes only where the
  silhouette's boundary moves, by the boundary's normal motion times its length. The points
  where the scanlines cross that boundary are edge samples, stratified along it: on each row the
  union of the spans is exact, so a span end is on the boundary exactly when the sample beside it,
  outside the span, is empty and no span reaches further (a fold of the surface, a rim or a foot
  ring, puts other contours a fraction of a pixel away; they are inside the union, not on its
  boundary). A row crossing moves the row's covered length by the crossing's motion along the
  row; weighted by the squared normal component along the row (and the column crossings by the
  other one), the two passes together are unbiased with bounded weights: :func:`scan_surrogate`,
  whose gradient is the estimate. Exact in expectation for the area-coverage loss, not a blurred
  surrogate.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

NEAR = 1e-3
"""Vertices closer to the camera plane than this (scene units) are dropped with their triangles."""


def supersampling(spp: int) -> int:
    """Sample rows (and columns) per pixel of each scan pass for ``spp`` samples per pixel (4 -> 2)."""
    return max(1, int(round(np.sqrt(max(int(spp), 1)))))


def camera_arrays(c2w: np.ndarray, fov_x: float, width: int) -> tuple[np.ndarray, float]:
    """World-to-camera matrices (n, 4, 4) of OpenGL camera-to-world ones and the focal length in
    pixels (``ipm.render.cameras.project``'s convention)."""
    return np.linalg.inv(np.asarray(c2w, np.float64)).astype(np.float32), float(0.5 * width / np.tan(0.5 * fov_x))


def project(vertices, w2c, focal: float, width: int, height: int, xp=jnp):
    """Pixel positions (V, 2) (x right, y down, pixel centres at +0.5) of world ``vertices`` (V, 3)
    and whether each lies in front of the camera (V,); ``xp``: jax.numpy or numpy."""
    p = vertices @ w2c[:3, :3].T + w2c[:3, 3]
    depth = -p[:, 2]
    front = depth > NEAR
    d = xp.where(front, depth, 1.0)
    return xp.stack([width / 2 + focal * p[:, 0] / d, height / 2 - focal * p[:, 1] / d], 1), front


def running_sum(x, axis: int = 0):
    """Integer running sum of ``x`` (counts, flags) along ``axis``, as ``jnp.cumsum``: the same
    integers by a parallel scan, which XLA's CPU backend runs 2-3 times faster than its cumsum."""
    return jax.lax.associative_scan(jnp.add, x.astype(jnp.int32), axis=axis)


def running_max(x):
    """Integer running maximum of ``x`` (1-D), as ``jax.lax.cummax`` (by the same scan)."""
    return jax.lax.associative_scan(jnp.maximum, x)


def row_ranges(ys, face_ok, height: int, xp=jnp):
    """First sample row (F,) whose line may cross each triangle (vertex rows ``ys`` (F, 3), sample
    units) and how many rows from there (0 for triangles not drawn): the spans :func:`spans`
    needs are their sum. ``xp``: jax.numpy or numpy."""
    r0 = xp.clip(xp.ceil(ys.min(1)) - 1, 0, height).astype(xp.int32)
    r1 = xp.clip(xp.ceil(ys.max(1)), 0, height).astype(xp.int32)
    return r0, xp.where(face_ok, xp.maximum(r1 - r0, 0), 0)


def spans(xy, faces, face_ok, jitter, width: int, budget: int) -> dict:
    """The row spans of every triangle, one per slot of a fixed ``budget``.

    ``xy`` (V, 2): vertices in sample units; ``jitter`` (R, 2) in [0, 1): sample (r, c) lies at
    (c + jitter[r, 0], r + jitter[r, 1]) (each row shifted on its own); ``faces`` (F, 3);
    ``face_ok`` (F,): triangles to draw. A triangle covers the samples of a row inside its span on
    that row (half-open, so a shared edge counts once). Per slot: ``row``, ``y`` (the row line),
    ``c0`` / ``c1`` (first covered column and first column after, unclipped; equal for a span
    between two samples, whose ends may still be the boundary), ``left`` / ``right`` (the vertex
    pairs of the edges the span ends on), ``live``, ``face`` (the triangle); and ``needed``, the
    spans the mesh needs (more than ``budget``: incomplete, call again with a larger one).
    """
    height = jitter.shape[0]
    tri = xy[faces]  # (F, 3, 2)
    r0, n = row_ranges(tri[..., 1], face_ok, height)
    end = running_sum(n)
    start = end - n
    needed = end[-1]
    # owner of each span slot: scatter each drawn triangle's index at its first slot, then a running max
    ids = jnp.where(n > 0, jnp.arange(len(n), dtype=jnp.int32), 0)
    owner = running_max(jnp.zeros(budget, jnp.int32).at[start].max(ids, mode="drop"))
    k = jnp.arange(budget, dtype=jnp.int32)
    row = jnp.clip(r0[owner] + k - start[owner], 0, height - 1)
    y = row.astype(xy.dtype) + jitter[row, 1]
    f = faces[owner]  # (B, 3)
    p = tri[owner]  # (B, 3, 2)
    q = jnp.roll(p, -1, axis=1)
    y0, y1 = p[..., 1], q[..., 1]
    crosses = (jnp.minimum(y0, y1) <= y[:, None]) & (y[:, None] < jnp.maximum(y0, y1))
    t = (y[:, None] - y0) / jnp.where(y1 != y0, y1 - y0, 1.0)
    x = p[..., 0] + t * (q[..., 0] - p[..., 0]) - jitter[row, 0][:, None]
    xl, xr = jnp.where(crosses, x, jnp.inf), jnp.where(crosses, x, -jnp.inf)
    il, ir = jnp.argmin(xl, 1), jnp.argmax(xr, 1)
    ends = jnp.stack([f, jnp.roll(f, -1, axis=1)], -1)  # (B, 3, 2): the triangle's edges
    take = jnp.arange(budget)
    c0 = jnp.ceil(jnp.clip(xl[take, il], -1.0, width + 1.0)).astype(jnp.int32)
    c1 = jnp.ceil(jnp.clip(xr[take, ir], -1.0, width + 1.0)).astype(jnp.int32)
    return {"row": row, "y": y, "c0": c0, "c1": c1, "left": ends[take, il], "right": ends[take, ir],
            "live": (k < needed) & jnp.any(crosses, 1), "needed": needed, "face": owner}


def covered_samples(s: dict, height: int, width: int):
    """Which samples (height, width) the spans ``s`` (:func:`spans`) cover."""
    c0, c1 = jnp.clip(s["c0"], 0, width), jnp.clip(s["c1"], 0, width)
    w = s["live"].astype(jnp.int32)
    diff = jnp.zeros((height, width + 1), jnp.int32).at[s["row"], c0].add(w).at[s["row"], c1].add(-w)
    return running_sum(diff[:, :width], axis=1) > 0


def scan_surrogate(xy, s: dict, covered, pixel_grad, ss: int, capacity: int):
    """A scalar whose gradient with respect to ``xy`` (V, 2, sample units, differentiable) is the
    scan pass's share of the edge-sampling estimate of d loss / d xy, where ``pixel_grad`` (H, W)
    is d loss / d (covered area of each pixel), ``s`` and ``covered`` the pass's spans and samples;
    and the number of candidate span ends (more than ``capacity``: some were left out).

    A span end is a boundary crossing when the sample beside it outside the span is empty (inside
    the image) and no other span ending in the same sample gap reaches further (ties: the lower
    slot). Its row's covered length moves with the crossing, d x; it counts as 1 / ss pixels of
    height, weighted by the squared row-wise component of the boundary's normal. Only the first
    ``capacity`` candidates (span ends beside an empty sample, a few per row) are examined."""
    h, w = covered.shape
    total, count = 0.0, 0
    for side, col, gap, sign in (("left", s["c0"], s["c0"] - 1, -1.0), ("right", s["c1"], s["c1"], 1.0)):
        cand = s["live"] & (gap >= 0) & (gap < w) & ~covered[s["row"], jnp.clip(gap, 0, w - 1)]
        pos = running_sum(cand) - 1
        count = jnp.maximum(count, pos[-1] + 1)
        k = jnp.full(capacity + 1, 0, jnp.int32).at[jnp.where(cand & (pos < capacity), pos, capacity)].set(
            jnp.arange(len(cand), dtype=jnp.int32))[:capacity]
        ok = jnp.arange(capacity) <= pos[-1]
        row, y, ends, col = s["row"][k], jax.lax.stop_gradient(s["y"][k]), s[side][k], col[k]
        a, b = xy[ends[:, 0]], xy[ends[:, 1]]
        d = b - a
        x = a[:, 0] + (y - a[:, 1]) / jnp.where(d[:, 1] != 0, d[:, 1], 1.0) * d[:, 0]  # differentiable
        x0 = jax.lax.stop_gradient(x)
        d0 = jax.lax.stop_gradient(d)
        weight = d0[:, 1] ** 2 / jnp.maximum(jnp.sum(d0**2, 1), 1e-12)
        cell = (row, jnp.clip(col, 0, w))
        key = sign * x0  # the span reaching furthest out has the largest key
        best = jnp.full((h, w + 1), -jnp.inf).at[cell].max(jnp.where(ok, key, -jnp.inf))
        ok = ok & (key == best[cell])
        slot = jnp.arange(capacity, dtype=jnp.int32)
        first = jnp.full((h, w + 1), capacity, jnp.int32).at[cell].min(jnp.where(ok, slot, capacity))
        ok = ok & (slot == first[cell])
        pr, pc = row // ss, jnp.floor(x0 / ss).astype(jnp.int32)
        ok = ok & (pc >= 0) & (pc < pixel_grad.shape[1])
        g = jnp.where(ok, pixel_grad[jnp.clip(pr, 0, pixel_grad.shape[0] - 1), jnp.clip(pc, 0, pixel_grad.shape[1] - 1)], 0.0)
        total = total + jnp.sum(jax.lax.stop_gradient(sign * g * weight / ss) * x / ss)
    return total, count


def pixel_area(covered, ss: int):
    """Per-pixel covered share (H, W) of the samples (H ss, W ss)."""
    # a sum of the ss x ss strided slices, not a mean over a reshape, which XLA's CPU backend hands to
    # a library call 15 times slower (256 px); counts of samples, so the same floats either way
    total = sum(covered[i::ss, j::ss].astype(jnp.int32) for i in range(ss) for j in range(ss))
    return total.astype(jnp.float32) / (ss * ss)


def view_area(vertices, w2c, focal: float, faces, width: int, height: int, ss: int, jitter, budget: int,
              pixel_grad_fn=None):
    """Covered area (H, W) of one view (the mean of the row and the column pass), the spans needed
    (the larger pass) and, given ``pixel_grad_fn(area) -> d loss / d area``, the edge-sampling
    surrogate of both passes (:func:`scan_surrogate`). ``jitter`` (H ss + W ss, 2): the rows',
    then the columns'."""
    xy, front = project(vertices, w2c, focal, width, height)
    face_ok = front[faces].all(1)
    xs = xy * ss
    passes = []
    for coords, jit, size in ((xs, jitter[: height * ss], width * ss), (xs[:, ::-1], jitter[height * ss:], height * ss)):
        s = spans(jax.lax.stop_gradient(coords), faces, face_ok, jit, size, budget)
        passes.append((coords, s, covered_samples(s, jit.shape[0], size)))
    area = 0.5 * (pixel_area(passes[0][2], ss) + pixel_area(passes[1][2], ss).T)
    needed = jnp.maximum(passes[0][1]["needed"], passes[1][1]["needed"])
    if pixel_grad_fn is None:
        return area, needed, 0.0
    g = pixel_grad_fn(jax.lax.stop_gradient(area))
    capacity = max(4 * (height + width) * ss, budget // 32)
    sur = 0.0
    for (coords, s, cov), grad in zip(passes, (g, g.T)):
        part, count = scan_surrogate(coords, s, cov, grad, ss, capacity)
        sur = sur + part
        needed = jnp.maximum(needed, jnp.where(count > capacity, 32 * count, 0))  # grow the budget
    return area, needed, sur
