"""Silhouettes (and class masks) in JAX: scanline coverage and edge-sampling gradients (the paper's own renderer).

The paper's last section replaces Mitsuba by "our own simple implementation of differentiable
renderer that uses edge sampling" for silhouettes. This is one, in pure JAX, so that the generator,
the camera, the coverage and the gradient are one ``jax.jit`` function of the parameters.

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

- **Class masks** (further face groups, up to two: a building's windows and its roof, where
  visible; one term per class, each the same as the one described here): every covered
  sample is a fragment at its triangle's plane's depth along the sample's ray, and the nearest
  triangle is the one seen (a z-buffer, :func:`visible_faces`). The class's boundary in the image
  is where the triangle seen changes class: at a span end whose triangle is the one seen inside
  and whose outside shows the other class (the window's own edge, or an occluder's); there the
  class's area moves with the crossing times the class difference, as the coverage does at the
  silhouette (:func:`class_surrogate`). Mitsuba's ``direct_projective`` underestimates this
  gradient on recessed panes (0.4-0.6 x central differences, ``tests/test_windows.py``).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ipm.errors import UserError
from ipm.render.programs import StoredProgram
from ipm.render.silhouette import group_count as _group_count, highlight_arrays

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
    end = jnp.cumsum(n)
    start = end - n
    needed = end[-1]
    # owner of each span slot: scatter each drawn triangle's index at its first slot, then a running max
    ids = jnp.where(n > 0, jnp.arange(len(n), dtype=jnp.int32), 0)
    owner = jax.lax.cummax(jnp.zeros(budget, jnp.int32).at[start].max(ids, mode="drop"))
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
    return jnp.cumsum(diff[:, :width], axis=1) > 0


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
        pos = jnp.cumsum(cand) - 1
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
    hs, ws = covered.shape
    return covered.reshape(hs // ss, ss, ws // ss, ss).mean((1, 3))


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


def face_planes(cam, faces):
    """Each triangle's plane in camera space: normals (F, 3) and offsets (F,), ``n . p = k`` on it."""
    p = cam[faces]
    n = jnp.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n, jnp.sum(n * p[:, 0], 1)


def ray_depth(planes, face, x, y, focal: float, width: int, height: int):
    """Depth (along the camera's -z) at which the ray through image point (``x``, ``y``) (pixels)
    meets the plane of triangle ``face`` (:func:`face_planes`); inf where it meets it behind the
    camera or not at all."""
    n, k = planes[0][face], planes[1][face]
    d = jnp.stack([(x - width / 2) / focal, -(y - height / 2) / focal, -jnp.ones_like(x)], -1)
    t = k / jnp.sum(n * d, -1)
    return jnp.where(t > 0, t, jnp.inf)


def _sample_xy(row, col, jitter, transposed: bool, ss: int):
    """Image position (pixels) of sample (``row``, ``col``) of a scan pass (:func:`spans`' grid;
    ``transposed``: the column pass, whose rows are image columns)."""
    a, b = (col + jitter[row, 0]) / ss, (row + jitter[row, 1]) / ss
    return (b, a) if transposed else (a, b)


def visible_faces(s: dict, jitter, planes, focal: float, width: int, height: int, ss: int, transposed: bool,
                  budget: int):
    """The triangle seen at each sample of a scan pass (rows x columns of the pass; -1: none) and
    the fragments needed: every sample a span covers (:func:`spans`) is a fragment, one per slot of
    a fixed ``budget``, at its triangle's plane's depth along the sample's ray; the nearest wins (a
    z-buffer, no gradient)."""
    hs, ws = jitter.shape[0], (height if transposed else width) * ss
    c0, c1 = jnp.clip(s["c0"], 0, ws), jnp.clip(s["c1"], 0, ws)
    n = jnp.where(s["live"], jnp.maximum(c1 - c0, 0), 0)
    end = jnp.cumsum(n)
    start, needed = end - n, end[-1]
    ids = jnp.where(n > 0, jnp.arange(len(n), dtype=jnp.int32), 0)
    span = jax.lax.cummax(jnp.zeros(budget, jnp.int32).at[start].max(ids, mode="drop"))
    k = jnp.arange(budget, dtype=jnp.int32)
    live = k < needed
    row, col, face = s["row"][span], c0[span] + k - start[span], s["face"][span]
    x, y = _sample_xy(row, col, jitter, transposed, ss)
    depth = jnp.where(live, ray_depth(planes, face, x, y, focal, width, height), jnp.inf)
    cell = jnp.where(live, row * ws + jnp.clip(col, 0, ws - 1), hs * ws)
    nearest = jnp.full(hs * ws + 1, jnp.inf).at[cell].min(depth)
    wins = live & (depth == nearest[cell]) & jnp.isfinite(depth)
    owner = jnp.full(hs * ws + 1, -1, jnp.int32).at[jnp.where(wins, cell, hs * ws)].max(face)
    return owner[:-1].reshape(hs, ws), needed


def class_surrogate(xy, s: dict, owner, cls, class_grad, jitter, planes, focal: float, width: int, height: int,
                    ss: int, transposed: bool, capacity: int):
    """A scalar whose gradient with respect to ``xy`` (V, 2, the pass's sample units) is the scan
    pass's share of the edge-sampling estimate of d loss / d xy for a class-mask term, where
    ``class_grad`` (the pass's H, W) is d loss / d (each pixel's area of the class ``cls`` (F,),
    1 for the class's triangles), ``owner`` the triangle seen at each sample (:func:`visible_faces`);
    and the number of candidate span ends (more than ``capacity``: some were left out).

    A span end is a crossing of the class's boundary when its triangle is the one seen at the
    sample inside it and the sample outside shows the other class (another triangle, or nothing);
    the crossing moves the row's area of the class by its motion times the difference. Of the span
    ends in one sample gap (a triangle's edge and its neighbour's, or an occluder's edge and the one
    it hides) the nearest triangle's counts, once. Weighted as in :func:`scan_surrogate`."""
    h, w = owner.shape
    cand, inside, gap, diff, ends, sign = [], [], [], [], [], []
    for side, col_in, col_out, sgn, g in (("left", s["c0"], s["c0"] - 1, -1.0, s["c0"]),
                                          ("right", s["c1"] - 1, s["c1"], 1.0, s["c1"])):
        o_in = owner[s["row"], jnp.clip(col_in, 0, w - 1)]
        o_out = owner[s["row"], jnp.clip(col_out, 0, w - 1)]
        d = cls[s["face"]] - jnp.where(o_out >= 0, cls[jnp.clip(o_out, 0)], 0.0)
        cand.append(s["live"] & (col_in >= 0) & (col_in < w) & (col_out >= 0) & (col_out < w)
                    & (o_in == s["face"]) & (d != 0))
        inside.append(col_in)
        gap.append(g)
        diff.append(d)
        ends.append(s[side])
        sign.append(jnp.full(col_in.shape, sgn, jnp.float32))
    cand, inside, gap, diff, ends, sign = (jnp.concatenate(a) for a in (cand, inside, gap, diff, ends, sign))
    slots = len(s["row"])
    pos = jnp.cumsum(cand) - 1
    count = pos[-1] + 1
    k = jnp.full(capacity + 1, 0, jnp.int32).at[jnp.where(cand & (pos < capacity), pos, capacity)].set(
        jnp.arange(len(cand), dtype=jnp.int32))[:capacity]
    ok = jnp.arange(capacity) <= pos[-1]
    span = k % slots
    row, y, face = s["row"][span], jax.lax.stop_gradient(s["y"][span]), s["face"][span]
    a, b = xy[ends[k, 0]], xy[ends[k, 1]]
    d = b - a
    x = a[:, 0] + (y - a[:, 1]) / jnp.where(d[:, 1] != 0, d[:, 1], 1.0) * d[:, 0]  # differentiable
    x0, d0 = jax.lax.stop_gradient(x), jax.lax.stop_gradient(d)
    weight = d0[:, 1] ** 2 / jnp.maximum(jnp.sum(d0**2, 1), 1e-12)
    px, py = _sample_xy(row, inside[k], jitter, transposed, ss)
    depth = jnp.where(ok, ray_depth(planes, face, px, py, focal, width, height), jnp.inf)
    cell = (row, jnp.clip(gap[k], 0, w))
    ok = ok & (depth == jnp.full((h, w + 1), jnp.inf).at[cell].min(depth)[cell])
    slot = jnp.arange(capacity, dtype=jnp.int32)
    ok = ok & (slot == jnp.full((h, w + 1), capacity, jnp.int32).at[cell].min(jnp.where(ok, slot, capacity))[cell])
    pr, pc = row // ss, jnp.floor(x0 / ss).astype(jnp.int32)
    ok = ok & (pc >= 0) & (pc < class_grad.shape[1])
    g = jnp.where(ok, class_grad[jnp.clip(pr, 0, class_grad.shape[0] - 1), jnp.clip(pc, 0, class_grad.shape[1] - 1)], 0.0)
    return jnp.sum(jax.lax.stop_gradient(sign[k] * g * diff[k] * weight / ss) * x / ss), count


def view_class_area(vertices, w2c, focal: float, faces, cls, width: int, height: int, ss: int, jitter,
                    budgets: tuple[int, int], grad_fn=None, n_classes: int = 1):
    """:func:`view_area` with classes: the covered area (H, W) and the area seen of each class
    k = 1 .. ``n_classes`` (``cls`` (F,): each face's class, 0 for none) (n_classes, H, W) of one
    view (means of the row and the column pass), the spans and fragments needed (2,), and given
    ``grad_fn(area, class_areas) -> (d loss / d area, d loss / d class areas)`` the edge-sampling
    surrogate of all (:func:`scan_surrogate`, :func:`class_surrogate` per class). Triangles of no
    area (a shared-positions generator's absent solids, collapsed to a point) are not drawn."""
    span_budget, frag_budget = budgets
    cam = vertices @ w2c[:3, :3].T + w2c[:3, 3]
    xy, front = project(vertices, w2c, focal, width, height)
    tri = xy[faces]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    face_ok = front[faces].all(1) & (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] != 0)
    planes = face_planes(jax.lax.stop_gradient(cam), faces)
    xs = xy * ss
    passes, needed = [], jnp.zeros(2, jnp.int32)
    for transposed, coords, jit, size in ((False, xs, jitter[: height * ss], width * ss),
                                          (True, xs[:, ::-1], jitter[height * ss:], height * ss)):
        s = spans(jax.lax.stop_gradient(coords), faces, face_ok, jit, size, span_budget)
        owner, frags = visible_faces(s, jit, planes, focal, width, height, ss, transposed, frag_budget)
        seen = jnp.where(owner >= 0, cls[jnp.clip(owner, 0)], 0.0)
        passes.append((transposed, coords, jit, s, covered_samples(s, jit.shape[0], size), owner, seen))
        needed = jnp.maximum(needed, jnp.stack([s["needed"], frags]))
    area = 0.5 * (pixel_area(passes[0][4], ss) + pixel_area(passes[1][4], ss).T)
    classes = range(1, n_classes + 1)
    class_area = jnp.stack([0.5 * (pixel_area(passes[0][6] == k, ss) + pixel_area(passes[1][6] == k, ss).T)
                            for k in classes])
    if grad_fn is None:
        return area, class_area, needed, 0.0
    g, gc = grad_fn(jax.lax.stop_gradient(area), jax.lax.stop_gradient(class_area))
    capacity = max(4 * (height + width) * ss, frag_budget // 16)  # candidate span ends of any term
    sur = 0.0
    for (transposed, coords, jit, s, cov, owner, _), grad, cgrads in zip(passes, (g, g.T), (gc, gc.transpose(0, 2, 1))):
        part, most = scan_surrogate(coords, s, cov, grad, ss, capacity)
        sur = sur + part
        for k, cgrad in zip(classes, cgrads):
            cpart, ccount = class_surrogate(coords, s, owner, (cls == k).astype(jnp.float32), cgrad, jit, planes,
                                            focal, width, height, ss, transposed, capacity)
            sur, most = sur + cpart, jnp.maximum(most, ccount)
        needed = needed.at[1].max(jnp.where(most > capacity, 16 * most, 0))  # grow the fragment budget
    return area, class_area, needed, sur


def pyramid_loss(image, target, levels: int, kind: str = "mse"):
    """``ipm.render.silhouette._pyramid_loss`` in JAX: the mean over ``levels`` levels of a 2 x 2
    mean pyramid of the ``"mse"`` or ``"dice"`` loss between ``image`` and ``target`` (H, W)."""
    errors = []
    for level in range(levels):
        if kind == "mse":
            errors.append(jnp.mean((image - target) ** 2))
        else:
            errors.append(1.0 - (2.0 * jnp.mean(image * target) + 1e-6) / (jnp.mean(image) + jnp.mean(target) + 1e-6))
        h, w = image.shape
        if level == levels - 1 or min(h, w) < 2:
            break
        h2, w2 = h // 2, w // 2
        image = image[: 2 * h2, : 2 * w2].reshape(h2, 2, w2, 2).mean((1, 3))
        target = target[: 2 * h2, : 2 * w2].reshape(h2, 2, w2, 2).mean((1, 3))
    return sum(errors[1:], errors[0]) / len(errors)


class EdgeRenderer:
    """Silhouettes of one triangle mesh seen by a fixed set of cameras, in JAX, with edge-sampling
    gradients: the same interface as ``ipm.render.silhouette.SilhouetteRenderer``, further face
    groups (a building's windows, its roof) included: each one's mask where visible (a z-buffer per
    sample) and each class term's gradient by edge sampling at the class's visible boundary.

    Parameters
    ----------
    c2w : (n, 4, 4) OpenGL camera-to-world matrices.
    fov_x : horizontal field of view in radians.
    width, height : image size in pixels.
    spp : samples per pixel and scan direction (rounded to a square: 4 -> 2 x 2; rows and
        columns each take that many, so a pixel's value averages twice ``spp`` samples).
    spans : the first span budget of :func:`spans` (default: from the first mesh drawn); it
        grows when a mesh needs more (each size is compiled once). With further face groups it is
        also the first fragment budget of :func:`visible_faces`.
    """

    def __init__(self, c2w: np.ndarray, fov_x: float, width: int, height: int, spp: int = 4,
                 spans: int | None = None):
        self.c2w, self.fov_x, self.width, self.height = np.asarray(c2w), fov_x, int(width), int(height)
        self.spp, self.ss = spp, supersampling(spp)
        self.w2c, self.focal = camera_arrays(self.c2w, fov_x, self.width)
        self._w2c = jnp.asarray(self.w2c)
        self.spans = spans
        self._budgets: dict = {}
        self._faces: dict = {}
        self._blocks: dict = {}
        self._classes: dict = {}  # class key -> each face's class on the device
        self._device: dict = {}  # id -> (a caller's array, its device copy): :meth:`_on_device`

    def _budget(self, key, vertices, faces: np.ndarray, classes: np.ndarray | None = None) -> int | tuple[int, int]:
        """The span budget for meshes of ``key`` (with ``classes``, the span and fragment budgets):
        on first sight ``spans``, or what ``vertices`` (a callable giving them) need in any view and
        direction with :func:`with_headroom`, so that the search rarely outgrows it."""
        if key not in self._budgets:
            if self.spans:
                self._budgets[key] = int(self.spans) if classes is None else (int(self.spans), int(self.spans))
                return self._budgets[key]
            v = np.asarray(vertices(), np.float32).reshape(-1, 3)
            need, frags = 0, 0
            for m in self.w2c:
                xy, front = project(v, m, self.focal, self.width, self.height, np)
                tri = (xy * self.ss)[faces]
                e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
                area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
                ok = front[faces].all(1) & ((area > 0) if classes is not None else True)  # view_class_area's
                for axis, size in ((1, self.height), (0, self.width)):
                    rows = row_ranges(tri[..., axis], ok, size * self.ss, np)[1]
                    need = max(need, int(rows.sum()))
                    frags = max(frags, int(area[ok].sum() + rows.sum()))
            spans = _round_up(with_headroom(need, grown=False) + 256)
            self._budgets[key] = spans if classes is None else (spans, _round_up(with_headroom(frags, grown=False) + 256))
        return self._budgets[key]

    def _run(self, key, groups: np.ndarray, vertices, run, classes: np.ndarray | None = None):
        """``run(faces, budget)`` -> (results..., budgets needed per view) with the budget of ``key``
        (:meth:`_budget`), each grown and run again while the mesh needs more than it has; the
        faces are put on the device once per ``key``."""
        budget = self._budget(key, vertices, groups, classes)
        faces = self._faces.setdefault(key, jnp.asarray(groups))
        while True:
            *out, needed = run(faces, budget)
            have = np.atleast_1d(budget)
            need = np.asarray(needed).reshape(-1, len(have)).max(0)
            if (need <= have).all():
                return out
            grown = tuple(_round_up(with_headroom(int(n), grown=True) + 1) if n > b else int(b) for n, b in zip(need, have))
            budget = self._budgets[key] = grown if classes is not None else grown[0]

    def _jitter(self, seed: int) -> np.ndarray:
        """Sample-grid jitter (n, H ss + W ss, 2) in [0, 1) for render ``seed``: each view's rows,
        then its columns (:func:`spans`)."""
        n = (self.height + self.width) * self.ss
        return np.random.default_rng([int(seed), 7]).random((len(self.c2w), n, 2)).astype(np.float32)

    def render(self, vertices: np.ndarray, faces, seed: int = 0) -> np.ndarray:
        """Masks (n, height, width) in [0, 1] of a fixed mesh (no gradients). With G face groups
        (``faces`` a list of G; vertices (V, 3) shared or (G, V, 3) one set per group),
        (n, G, height, width): the silhouette and the mask of each further group where visible."""
        vertices = np.asarray(vertices, np.float32)
        jitter = self._jitter(seed)
        n_groups = _group_count(faces)
        if n_groups == 1:
            groups = _face_classes(faces)[0]
            v = jnp.asarray(vertices.reshape(-1, 3))
            masks, = self._run(("render", *_faces_key(groups)), groups, lambda: v, lambda f, budget: _render_fn(
                self.width, self.height, self.ss, budget)(v, f, self._w2c, self.focal, jitter))
            return np.asarray(masks, np.float32)
        blocks = n_groups if vertices.ndim == 3 and len(vertices) == n_groups else 1
        groups, classes = _face_classes(faces, vertices.shape[-2], blocks)
        v, cls = jnp.asarray(vertices.reshape(-1, 3)), jnp.asarray(classes)
        area, class_area = self._run(("render", *_faces_key(groups), *_class_sizes(classes)), groups, lambda: v,
                                     lambda f, budget: _class_render_fn(self.width, self.height, self.ss, budget,
                                                                        n_groups - 1)(
                                         v, f, cls, self._w2c, self.focal, jitter), classes)
        return np.concatenate([np.asarray(area, np.float32)[:, None], np.asarray(class_area, np.float32)], 1)

    def loss_and_grad(self, vertex_fn: Callable, z: np.ndarray, faces, n_vertices: int,
                      targets: np.ndarray, seed: int = 0, highlight_targets: np.ndarray | None = None,
                      highlight_weight: float = 0.0, highlight_levels: int = 1,
                      highlight_loss: str = "mse") -> tuple[float, np.ndarray]:
        """Mean over views of the pixel MSE between rendered and target masks (plus, per further
        face group k, ``highlight_weight[k]`` times the ``highlight_loss`` of its masks against
        ``highlight_targets[:, k]``, ``"mse"`` or ``"dice"``, averaged over ``highlight_levels``
        levels of a 2 x 2 mean pyramid: :func:`pyramid_loss`), and d loss / d z. One further group
        may give its targets (n, H, W) and weight as a number. ``vertex_fn``: pure JAX z (m,) ->
        flattened world vertices, (3 V,) shared by the face groups or (G * 3 V,) one block per
        group (``n_vertices`` = V)."""
        highlight, n_groups = None, _group_count(faces)
        if n_groups > 1:
            if highlight_loss not in ("mse", "dice"):
                raise ValueError(f"unknown class-mask loss {highlight_loss!r} (known: mse, dice)")
            class_targets, weights = highlight_arrays(targets, n_groups - 1, highlight_targets, highlight_weight)
            highlight = (class_targets, weights, int(highlight_levels), highlight_loss)
        loss, grad = self._call(vertex_fn, np.asarray(z)[None], faces, targets, [seed], batched=False,
                                n_vertices=n_vertices, highlight=highlight)
        return float(loss[0]), grad[0]

    def loss_and_grad_batch(self, vertex_fn: Callable, zs: np.ndarray, faces, targets: np.ndarray,
                            seeds) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`loss_and_grad` of several points ``zs`` (b, m) of one topology in one call, each
        with its render seed: losses (b,) and gradients (b, m) (silhouettes)."""
        return self._call(vertex_fn, np.asarray(zs), faces, targets, list(seeds), batched=True)

    def _call(self, vertex_fn, zs, faces, targets, seeds, batched: bool, n_vertices: int | None = None,
              highlight: tuple | None = None):
        """Losses (b,) and gradients (b, m) of ``zs`` (b, m), one compiled call (batched) or one per
        point; ``highlight``: (class targets (n, K, H, W), weights (K,), levels, loss) of the K
        further face groups."""
        zj = np.asarray(zs, np.float32)  # numpy into the compiled calls: one transfer each, no eager ops
        targets = self._on_device(targets)
        jitter = np.stack([self._jitter(s) for s in seeds])
        if highlight is not None:
            return self._class_call(vertex_fn, zj, faces, targets, jitter, n_vertices, highlight)
        if _group_count(faces) > 1:
            raise UserError("the jax renderer's batched calls draw silhouettes only")
        groups = _face_classes(faces)[0]
        z_in, jitter_in = (zj, jitter) if batched else (zj[0], jitter[0])

        def run(f, budget):
            fn = _loss_fn(vertex_fn, self.width, self.height, self.ss, budget, batched)
            return fn(z_in, f, targets, self._w2c, self.focal, jitter_in)

        loss, grad = self._run((vertex_fn, *_faces_key(groups)), groups, lambda: vertex_fn(zj[0]), run)
        grad = np.nan_to_num(np.asarray(grad, np.float64), nan=0.0, posinf=0.0, neginf=0.0).reshape(len(zs), -1)
        return np.asarray(loss, np.float64).reshape(len(zs)), grad

    def _on_device(self, array) -> jnp.ndarray:
        """``array`` (float32) on the device, copied once per array object a caller passes again
        and again (a search's target masks, at every step); the last few are kept."""
        if id(array) not in self._device:
            if len(self._device) >= 4:
                self._device.clear()
            self._device[id(array)] = (array, jnp.asarray(np.asarray(array, np.float32)))  # holds it: ids stay
        return self._device[id(array)][1]

    def _class_call(self, vertex_fn, zj, faces, targets, jitter, n_vertices: int, highlight: tuple):
        """:meth:`_call` with a class-mask term, one point after another: the generator's vertices,
        the render program's loss and d loss / d vertices, then the generator's pullback."""
        if (vertex_fn, n_vertices) not in self._blocks:
            size = int(np.prod(jax.eval_shape(vertex_fn, zj[0]).shape))
            self._blocks[vertex_fn, n_vertices] = size // (3 * int(n_vertices))
        groups, classes = _face_classes(faces, n_vertices, self._blocks[vertex_fn, n_vertices])
        key = ("class", *_faces_key(groups), *_class_sizes(classes))
        if key not in self._classes:
            self._classes[key] = jnp.asarray(classes)
        cls, class_targets = self._classes[key], self._on_device(highlight[0])
        losses, grads = [], []
        for z, j in zip(zj, jitter):
            vertices = vertex_fn(z)
            loss, dv = self._run(key, groups, lambda: vertices, lambda f, budget: _class_loss_fn(
                self.width, self.height, self.ss, budget, tuple(highlight[1:]))(
                vertices, f, cls, targets, class_targets, self._w2c, self.focal, j), classes)
            losses.append(float(loss))
            grads.append(np.asarray(_pullback(vertex_fn)(z, dv), np.float64))
        return np.array(losses), np.nan_to_num(np.stack(grads), nan=0.0, posinf=0.0, neginf=0.0)


def with_headroom(spans: int, grown: bool) -> int:
    """A span budget for meshes needing ``spans``, on first sight or after outgrowing the last. Each
    new budget is a new program to compile: about 2 s on a CPU, 8-10 s on an H100, where a loss
    costs about the same at any budget (4 ms from 64 to 512 px) while on a CPU the work grows with
    it. So a third (a quarter when grown) more on the CPU, and three times as many on a GPU
    (where a cup's reconstruction compiled one or two grown budgets a stage)."""
    if jax.default_backend() != "cpu":
        return 3 * int(spans)
    return int(spans * 1.25) if grown else int(spans) * 4 // 3


def _round_up(n: int) -> int:
    """``n`` rounded up to one of 8 sizes per octave (at most 12.5 % more work than asked for)."""
    step = max(1 << max(int(n).bit_length() - 4, 0), 1)
    return -(-int(n) // step) * step


def _faces_key(faces: np.ndarray) -> tuple:
    """A cheap key telling face arrays apart (shape and both ends)."""
    return faces.shape, faces[:16].tobytes(), faces[-16:].tobytes()


def _face_classes(faces, n_vertices: int = 0, blocks: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
    """One face array (F, 3) of G face groups (:func:`_group_count`) and, for more than one, each
    face's class (F,): its group's index (0: the silhouette's alone). With one vertex block per
    group (``blocks`` G) group g's indices move past the first g blocks of ``n_vertices``."""
    groups = [np.asarray(f, np.int32).reshape(-1, 3) for f in (faces if isinstance(faces, (list, tuple)) else [faces])]
    if _group_count(faces) == 1:
        return np.ascontiguousarray(groups[0]), None
    shift = int(n_vertices) if blocks == len(groups) else 0
    classes = np.concatenate([np.full(len(g), k) for k, g in enumerate(groups)]).astype(np.float32)
    return np.ascontiguousarray(np.concatenate([g + k * shift for k, g in enumerate(groups)])), classes


def _class_sizes(classes: np.ndarray) -> tuple[int, ...]:
    """The number of faces of each class, a part of the keys of meshes with classes."""
    return tuple(int(c) for c in np.bincount(classes.astype(np.int64)))


@lru_cache(maxsize=64)
def _render_fn(width: int, height: int, ss: int, budget: int) -> StoredProgram:
    """(vertices, faces, w2c, focal, jitter) -> (pixel areas (n, H, W), spans needed per view)."""

    def fn(vertices, faces, w2c, focal, jitter):
        area, needed, _ = jax.vmap(lambda m, j: view_area(vertices, m, focal, faces, width, height, ss, j, budget))(
            w2c, jitter)
        return area, needed

    return _stored(fn, "render", width, height, ss, budget)


@lru_cache(maxsize=64)
def _class_render_fn(width: int, height: int, ss: int, budgets: tuple[int, int], n_classes: int = 1) -> StoredProgram:
    """(vertices, faces, classes, w2c, focal, jitter) -> (pixel areas (n, H, W), the classes'
    visible areas (n, n_classes, H, W), spans and fragments needed per view (n, 2))."""

    def fn(vertices, faces, classes, w2c, focal, jitter):
        area, class_area, needed, _ = jax.vmap(lambda m, j: view_class_area(
            vertices, m, focal, faces, classes, width, height, ss, j, budgets, n_classes=n_classes))(w2c, jitter)
        return area, class_area, needed

    return _stored(fn, "class_render", width, height, ss, budgets, n_classes)


@lru_cache(maxsize=64)
def _loss_fn(vertex_fn: Callable, width: int, height: int, ss: int, budget: int, batched: bool = False):
    """jit(z, faces, targets, w2c, focal, jitter) -> (loss, d loss / d z, spans needed per view):
    the generator's vertices and pullback around :func:`_silhouette_loss` in one program. The faces
    are an argument, not a constant (XLA would fold it into the program at every compilation).
    ``batched``: over a leading axis of ``z`` and ``jitter`` (individuals of one topology)."""
    render = _silhouette_loss(width, height, ss, budget, batched)
    vertices_of = jax.vmap(vertex_fn) if batched else vertex_fn

    def fn(z, faces, targets, w2c, focal, jitter):
        vertices, pullback = jax.vjp(vertices_of, z)
        loss, grad, needed = render.inline(vertices, faces, targets, w2c, focal, jitter)
        return loss, pullback(grad)[0], needed

    return jax.jit(fn)


@lru_cache(maxsize=64)
def _silhouette_loss(width: int, height: int, ss: int, budget: int, batched: bool) -> StoredProgram:
    """(flattened vertices, faces, targets, w2c, focal, jitter) -> (loss, d loss / d vertices,
    spans needed per view), over a leading axis of vertices and jitter when ``batched``."""

    def surrogate(vertices, faces, targets, w2c, focal, jitter):
        vertices = vertices.reshape(-1, 3)
        n_views = len(targets)

        def view(m, target, j):
            area, needed, sur = view_area(vertices, m, focal, faces, width, height, ss, j, budget,
                                          lambda a: 2.0 * (a - target) / a.size / n_views)
            return jnp.mean((jax.lax.stop_gradient(area) - target) ** 2) / n_views, sur, needed

        loss, sur, needed = jax.vmap(view)(w2c, targets, jitter)
        return jnp.sum(sur), (jnp.sum(loss), needed)

    def fn(vertices, faces, targets, w2c, focal, jitter):
        (_, (loss, needed)), grad = jax.value_and_grad(surrogate, has_aux=True)(vertices, faces, targets, w2c,
                                                                                 focal, jitter)
        return loss, grad, needed

    if batched and jax.default_backend() == "cpu":  # one after another in one program: XLA's CPU
        single = fn  # scatters with a batch dimension cost more than the individuals one by one

        def fn(vertices, faces, targets, w2c, focal, jitter):
            return jax.lax.map(lambda a: single(a[0], faces, targets, w2c, focal, a[1]), (vertices, jitter))
    elif batched:
        fn = jax.vmap(fn, in_axes=(0, None, None, None, None, 0))
    return _stored(fn, "silhouette_loss", width, height, ss, budget, batched)


@lru_cache(maxsize=64)
def _class_loss_fn(width: int, height: int, ss: int, budgets: tuple[int, int], highlight: tuple) -> StoredProgram:
    """(vertices, faces, classes, targets, class_targets, w2c, focal, jitter) -> (loss, d loss /
    d vertices, spans and fragments needed per view (n, 2)) with the class-mask terms ``highlight``
    (a weight per class, pyramid levels, loss; class targets (n, K, H, W)). The generator is not in
    the program (a building's takes longer to compile than the renderer, and each resolution and
    budget is a program of its own): its vector-Jacobian product is compiled once (:func:`_pullback`)."""
    weights, levels, kind = highlight

    def class_loss(class_area, class_target):
        return sum(weights[k] * pyramid_loss(class_area[k], class_target[k], levels, kind) for k in range(len(weights)))

    def surrogate(vertices, faces, classes, targets, class_targets, w2c, focal, jitter):
        n_views = len(targets)

        def view(m, target, class_target, j):
            def grads(a, c):
                return (2.0 * (a - target) / a.size / n_views,
                        jax.grad(lambda x: class_loss(x, class_target))(c) / n_views)

            area, class_area, needed, sur = view_class_area(vertices.reshape(-1, 3), m, focal, faces, classes, width,
                                                            height, ss, j, budgets, grads, n_classes=len(weights))
            area, class_area = jax.lax.stop_gradient(area), jax.lax.stop_gradient(class_area)
            loss = jnp.mean((area - target) ** 2) + class_loss(class_area, class_target)
            return loss / n_views, sur, needed

        loss, sur, needed = jax.vmap(view)(w2c, targets, class_targets, jitter)
        return jnp.sum(sur), (jnp.sum(loss), needed)

    def fn(*args):
        (_, (loss, needed)), grad = jax.value_and_grad(surrogate, has_aux=True)(*args)
        return loss, grad, needed

    return _stored(fn, "class_loss", width, height, ss, budgets, highlight)


def _stored(fn: Callable, *name) -> StoredProgram:
    """``fn``, a program of this file's renderer with the settings ``name``, kept between processes."""
    return StoredProgram(" ".join(map(str, name)), fn, (__file__,))


@lru_cache(maxsize=64)
def _pullback(vertex_fn: Callable):
    """jit(z, d loss / d vertices) -> d loss / d z: the generator's vector-Jacobian product."""
    return jax.jit(lambda z, cotangent: jax.vjp(vertex_fn, z)[1](cotangent)[0])
