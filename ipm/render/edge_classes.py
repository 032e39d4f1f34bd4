"""Class masks (a building's windows, its roof) where visible and their edge-sampling gradient,
in JAX (the kernels of ``ipm.render.edges`` beside the silhouette's, ``ipm.render.edge_scan``).

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

import jax
import jax.numpy as jnp

from ipm.render.edge_scan import (covered_samples, pixel_area, project, running_max, running_sum, scan_surrogate,
                                  spans)


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
    # n . (dx, dy, -1) written out: as a reduction over 3-vectors XLA's CPU backend hands it to a
    # library call that took a third to a half of a building's class-mask loss (on the fragments)
    t = k / (n[..., 0] * ((x - width / 2) / focal) + n[..., 1] * (-(y - height / 2) / focal) - n[..., 2])
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
    end = running_sum(n)
    start, needed = end - n, end[-1]
    ids = jnp.where(n > 0, jnp.arange(len(n), dtype=jnp.int32), 0)
    span = running_max(jnp.zeros(budget, jnp.int32).at[start].max(ids, mode="drop"))
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
    pos = running_sum(cand) - 1
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


def front_facing(e1, e2):
    """Whether triangles with projected edges ``e1``, ``e2`` (F, 2; pixels, y down) face the camera
    (counter-clockwise seen from outside a closed, outward-facing solid)."""
    return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0


def view_class_area(vertices, w2c, focal: float, faces, cls, width: int, height: int, ss: int, jitter,
                    budgets: tuple[int, int], grad_fn=None, n_classes: int = 1, cull: bool = False):
    """:func:`view_area` with classes: the covered area (H, W) and the area seen of each class
    k = 1 .. ``n_classes`` (``cls`` (F,): each face's class, 0 for none) (n_classes, H, W) of one
    view (means of the row and the column pass), the spans and fragments needed (2,), and given
    ``grad_fn(area, class_areas) -> (d loss / d area, d loss / d class areas)`` the edge-sampling
    surrogate of all (:func:`scan_surrogate`, :func:`class_surrogate` per class). Triangles of no
    area (a shared-positions generator's absent solids, collapsed to a point) are not drawn, nor
    with ``cull`` those facing away (:func:`front_facing`): for closed, outward-facing solids the
    same coverage, boundaries and visible classes from half the spans and fragments."""
    span_budget, frag_budget = budgets
    cam = vertices @ w2c[:3, :3].T + w2c[:3, 3]
    xy, front = project(vertices, w2c, focal, width, height)
    tri = xy[faces]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    face_ok = front[faces].all(1) & (front_facing(e1, e2) if cull else e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] != 0)
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
