"""Silhouettes in JAX: scanline coverage and edge-sampling gradients (the paper's own renderer).

The paper's last section replaces Mitsuba by "our own simple implementation of differentiable
renderer that uses edge sampling" for silhouettes. This is one, in pure JAX, so that the generator,
the camera, the coverage and the gradient are one ``jax.jit`` function of the parameters:

- **Coverage** (no gradient): every triangle is cut into the pixel rows it crosses (a fixed budget
  of row spans, :func:`coverage`), each span adds +1 / -1 to a difference image, and a running sum
  along the rows counts the triangles over each sample. ``ss`` x ``ss`` samples per pixel on a grid
  whose rows are shifted at random per call (so a pixel's value is an unbiased estimate of its
  covered area, as Mitsuba's box filter with ``spp`` samples is, and pixels' errors independent).
- **Gradient** (Li et al. 2018, "Differentiable Monte Carlo ray tracing through edge sampling"):
  a pixel's covered area changes only where a silhouette edge moves, by the edge's normal motion
  times its length. Silhouette edges are the mesh edges whose incident triangles all lie on one side
  of them in the image (contours of closed meshes, borders of open ones); points are drawn on
  them uniformly by length (stratified), a point counts where the image just outside it is empty
  (not hidden by other geometry), and the loss gradient there, d loss / d coverage of its pixel,
  weights the point's outward motion: :func:`edge_surrogate`, whose gradient is the estimate.
  The estimate is exact in expectation for the area-coverage loss, not a blurred surrogate.

Only silhouettes: a second face group (a building's window mask needs visibility) is Mitsuba's
(``ipm.render.silhouette``).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ipm.errors import UserError

X_FACTOR = 1
NEAR = 1e-3
"""Vertices closer to the camera plane than this (scene units) are dropped with their triangles."""


def supersampling(spp: int, x_factor: int = 1) -> tuple[int, int]:
    """Sample rows and columns per pixel for ``spp`` samples per pixel (4 -> 2 x 2), with
    ``x_factor`` times as many columns (cheap: a span covers any number of columns at once)."""
    s = max(1, int(round(np.sqrt(max(int(spp), 1)))))
    return s, s * int(x_factor)


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
    units) and how many rows from there (0 for triangles not drawn): the spans :func:`coverage`
    needs are their sum. ``xp``: jax.numpy or numpy."""
    r0 = xp.clip(xp.ceil(ys.min(1)) - 1, 0, height).astype(xp.int32)
    r1 = xp.clip(xp.ceil(ys.max(1)), 0, height).astype(xp.int32)
    return r0, xp.where(face_ok, xp.maximum(r1 - r0, 0), 0)


def coverage(xy, faces, face_ok, jitter, width: int, budget: int):
    """Which samples (R, width) any triangle covers, and the row spans it took.

    ``xy`` (V, 2): vertices in sample units; ``jitter`` (R, 2) in [0, 1): sample (r, c) lies at
    (c + jitter[r, 0], r + jitter[r, 1]), a grid with each row shifted on its own (a pixel's
    samples are stratified, and neighbouring pixels' errors along an edge independent, as with
    independent samples; one shift for the whole grid would make the error of every pixel along a
    straight edge the same). ``faces`` (F, 3); ``face_ok`` (F,): triangles to draw. A triangle
    covers the samples of a row inside its span on that row (half-open, so shared edges count
    once). ``budget``: the number of (triangle, row) spans provided; the second result is the number
    needed (more than ``budget``: the image is incomplete, call again with a larger one).
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
    p = tri[owner]  # (B, 3, 2)
    q = jnp.roll(p, -1, axis=1)
    y0, y1 = p[..., 1], q[..., 1]
    crosses = (jnp.minimum(y0, y1) <= y[:, None]) & (y[:, None] < jnp.maximum(y0, y1))
    t = (y[:, None] - y0) / jnp.where(y1 != y0, y1 - y0, 1.0)
    x = p[..., 0] + t * (q[..., 0] - p[..., 0]) - jitter[row, 0][:, None]
    c0 = jnp.clip(jnp.ceil(jnp.min(jnp.where(crosses, x, jnp.inf), 1)), 0, width).astype(jnp.int32)
    c1 = jnp.clip(jnp.ceil(jnp.max(jnp.where(crosses, x, -jnp.inf), 1)), 0, width).astype(jnp.int32)
    w = ((k < needed) & (c1 > c0)).astype(jnp.int32)
    diff = jnp.zeros((height, width + 1), jnp.int32).at[row, c0].add(w, mode="drop").at[row, c1].add(-w, mode="drop")
    return jnp.cumsum(diff[:, :width], axis=1) > 0, needed


def edge_table(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's unique edges (E, 2) and, per edge, the vertex opposite it in each incident
    triangle (E, K), -1 where an edge has fewer than K triangles."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if not len(faces):
        return np.zeros((0, 2), np.int32), np.zeros((0, 1), np.int32)
    ends = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    opposite = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    ends = np.sort(ends, 1)
    keep = ends[:, 0] != ends[:, 1]
    ends, opposite = ends[keep], opposite[keep]
    edges, inverse = np.unique(ends, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    counts = np.bincount(inverse, minlength=len(edges))
    slot = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)
    table = -np.ones((len(edges), max(int(counts.max()), 1)), np.int64)
    table[inverse[order], slot] = opposite[order]
    return edges.astype(np.int32), table.astype(np.int32)


def silhouette_edges(xy, front, edges, opposite):
    """Per edge: whether it bounds the drawn region (every incident triangle on one side of it in
    the image; triangles seen edge-on do not count) and its outward unit normal (E, 2)."""
    a, b = xy[edges[:, 0]], xy[edges[:, 1]]
    d = b - a
    c = xy[jnp.maximum(opposite, 0)]  # (E, K, 2)
    side = d[:, None, 0] * (c[..., 1] - a[:, None, 1]) - d[:, None, 1] * (c[..., 0] - a[:, None, 0])
    drawn = (opposite >= 0) & front[jnp.maximum(opposite, 0)]
    pos = jnp.any(drawn & (side > 0), 1)
    neg = jnp.any(drawn & (side < 0), 1)
    sil = (pos != neg) & front[edges[:, 0]] & front[edges[:, 1]]
    length = jnp.sqrt(jnp.sum(d * d, 1))
    perp = jnp.stack([-d[:, 1], d[:, 0]], 1) / jnp.maximum(length, 1e-12)[:, None]
    return sil, jnp.where(pos[:, None], -perp, perp)


def edge_surrogate(xy, front, covered, pixel_grad, edges, opposite, ss: int, xi, n_samples: int):
    """A scalar whose gradient with respect to ``xy`` (V, 2, pixels) is the edge-sampling estimate
    of d loss / d xy, where ``pixel_grad`` (H, W) is d loss / d (covered area of each pixel) and
    ``covered`` (H ss, W ss) the samples' coverage (:func:`coverage`).

    ``n_samples`` points, stratified by ``xi`` (n_samples,) in [0, 1), spread uniformly over the
    silhouette edges' total length; each weighs that length / ``n_samples`` pixels times the loss
    gradient of its pixel, where the sample two sample spacings outside it is empty (the samples
    of a row lie within one spacing of where they would be without jitter)."""
    h, w = pixel_grad.shape
    sil, normal = silhouette_edges(jax.lax.stop_gradient(xy), front, edges, opposite)
    a, b = xy[edges[:, 0]], xy[edges[:, 1]]
    length = jnp.where(sil, jnp.sqrt(jnp.sum(jax.lax.stop_gradient(b - a) ** 2, 1)), 0.0)
    end = jnp.cumsum(length)
    total = end[-1]
    u = (jnp.arange(n_samples) + xi) / n_samples * total
    e = jnp.clip(jnp.searchsorted(end, u, side="right"), 0, len(length) - 1)
    t = jnp.clip((u - (end[e] - length[e])) / jnp.maximum(length[e], 1e-12), 0.0, 1.0)
    t = jax.lax.stop_gradient(t)
    point = a[e] + t[:, None] * (b[e] - a[e])  # differentiable in xy
    p0 = jax.lax.stop_gradient(point)
    n = normal[e]
    scale = jnp.asarray(ss[::-1], p0.dtype)  # (x, y) samples per pixel
    out = p0 * scale + 2.0 * n  # the sample cell two spacings outside
    oc, orow = jnp.floor(out[:, 0]).astype(jnp.int32), jnp.floor(out[:, 1]).astype(jnp.int32)
    hs, ws = covered.shape
    inside = (orow >= 0) & (orow < hs) & (oc >= 0) & (oc < ws)
    blocked = inside & covered[jnp.clip(orow, 0, hs - 1), jnp.clip(oc, 0, ws - 1)]
    pc, pr = jnp.floor(p0[:, 0]).astype(jnp.int32), jnp.floor(p0[:, 1]).astype(jnp.int32)
    on_image = (pr >= 0) & (pr < h) & (pc >= 0) & (pc < w)
    g = jnp.where(on_image & ~blocked & (length[e] > 0),
                  pixel_grad[jnp.clip(pr, 0, h - 1), jnp.clip(pc, 0, w - 1)], 0.0)
    weight = jax.lax.stop_gradient(g * total / n_samples)
    return jnp.sum(weight * jnp.sum(n * point, 1))


def render_view(vertices, w2c, focal: float, faces, width: int, height: int, ss: tuple[int, int], jitter,
                budget: int):
    """Covered samples (H sy, W sx) of one view and the row spans needed (:func:`coverage`)."""
    xy, front = project(vertices, w2c, focal, width, height)
    return coverage(xy * jnp.asarray(ss[::-1], xy.dtype), faces, front[faces].all(1), jitter, width * ss[1], budget)


def pixel_area(covered, ss: tuple[int, int]):
    """Per-pixel covered share (H, W) of the samples (H sy, W sx)."""
    hs, ws = covered.shape
    return covered.reshape(hs // ss[0], ss[0], ws // ss[1], ss[1]).mean((1, 3))


class EdgeRenderer:
    """Silhouettes of one triangle mesh seen by a fixed set of cameras, in JAX, with edge-sampling
    gradients: the same interface as ``ipm.render.silhouette.SilhouetteRenderer``.

    Parameters
    ----------
    c2w : (n, 4, 4) OpenGL camera-to-world matrices.
    fov_x : horizontal field of view in radians.
    width, height : image size in pixels.
    spp : samples per pixel (rounded to a square: 4 -> 2 x 2).
    edge_samples : points per view on the silhouette edges (default 8 per pixel of image width).
    spans : the first span budget of :func:`coverage` (default: from the first mesh drawn); it
        grows when a mesh needs more (each size is compiled once).
    """

    def __init__(self, c2w: np.ndarray, fov_x: float, width: int, height: int, spp: int = 4,
                 edge_samples: int | None = None, spans: int | None = None):
        self.c2w, self.fov_x, self.width, self.height = np.asarray(c2w), fov_x, int(width), int(height)
        self.spp, self.ss = spp, supersampling(spp, X_FACTOR)
        self.w2c, self.focal = camera_arrays(self.c2w, fov_x, self.width)
        self.edge_samples = int(edge_samples or 8 * self.width)
        self.spans = spans
        self._budgets: dict = {}

    def _budget(self, key, vertices, faces: np.ndarray) -> int:
        """The span budget for meshes of ``key``: on first sight ``spans``, or a third more than
        ``vertices`` (a callable giving them) need in any view, so that the search rarely outgrows it."""
        if key not in self._budgets:
            if self.spans:
                self._budgets[key] = int(self.spans)
            else:
                v = np.asarray(vertices(), np.float32).reshape(-1, 3)
                need = 0
                for m in self.w2c:
                    xy, front = project(v, m, self.focal, self.width, self.height, np)
                    tri = (xy * self.ss[0])[faces]
                    rows = row_ranges(tri[..., 1], front[faces].all(1), self.height * self.ss[0], np)[1]
                    need = max(need, int(rows.sum()))
                self._budgets[key] = _round_up(need * 4 // 3 + 256)
        return self._budgets[key]

    def _grown(self, key, needed: int) -> int:
        self._budgets[key] = _round_up(int(needed * 1.25) + 1)
        return self._budgets[key]

    def render(self, vertices: np.ndarray, faces, seed: int = 0) -> np.ndarray:
        """Masks (n, height, width) in [0, 1] of a fixed mesh (no gradients)."""
        groups = _single_group(faces)
        vertices = jnp.asarray(np.asarray(vertices, np.float32).reshape(-1, 3))
        key = ("render", groups.shape, groups[:16].tobytes(), groups[-16:].tobytes())
        budget = self._budget(key, lambda: vertices, groups)
        while True:
            masks, needed = _render_fn(self.width, self.height, self.ss, budget)(
                vertices, jnp.asarray(groups), jnp.asarray(self.w2c), self.focal, _jitter(seed, len(self.c2w), self.height * self.ss[0]))
            needed = int(np.max(needed))
            if needed <= budget:
                return np.asarray(masks, np.float32)
            budget = self._grown(key, needed)

    def loss_and_grad(self, vertex_fn: Callable, z: np.ndarray, faces, n_vertices: int,
                      targets: np.ndarray, seed: int = 0, highlight_targets: np.ndarray | None = None,
                      highlight_weight: float = 0.0, highlight_levels: int = 1,
                      highlight_loss: str = "mse") -> tuple[float, np.ndarray]:
        """Mean over views of the pixel MSE between rendered and target masks, and d loss / d z
        (``vertex_fn``: pure JAX z (m,) -> flattened world vertices). A second face group (a class
        mask) is refused: it needs visibility, which only the Mitsuba renderer draws."""
        groups = _single_group(faces)
        key = (vertex_fn, groups.shape, groups[:16].tobytes(), groups[-16:].tobytes())
        zj = jnp.asarray(np.asarray(z, np.float32))
        budget = self._budget(key, lambda: vertex_fn(zj), groups)
        targets = jnp.asarray(np.asarray(targets, np.float32))
        xi = _strata(seed, len(self.c2w), self.edge_samples)
        while True:
            fn = _loss_fn(vertex_fn, self.width, self.height, self.ss, budget, self.edge_samples)
            loss, grad, needed = fn(zj, _tables(groups.tobytes(), len(groups)), targets, jnp.asarray(self.w2c),
                                    self.focal, _jitter(seed, len(self.c2w), self.height * self.ss[0]), xi)
            needed = int(np.max(needed))
            if needed <= budget:
                break
            budget = self._grown(key, needed)
        grad = np.asarray(grad, np.float64)
        return float(loss), np.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)

    def loss_and_grad_batch(self, vertex_fn: Callable, zs: np.ndarray, faces, targets: np.ndarray,
                            seeds) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`loss_and_grad` of several points ``zs`` (b, m) of one topology in one call, each
        with its render seed: losses (b,) and gradients (b, m)."""
        groups = _single_group(faces)
        key = (vertex_fn, groups.shape, groups[:16].tobytes(), groups[-16:].tobytes())
        zj = jnp.asarray(np.asarray(zs, np.float32))
        budget = self._budget(key, lambda: vertex_fn(zj[0]), groups)
        targets = jnp.asarray(np.asarray(targets, np.float32))
        n = len(self.c2w)
        jitter = jnp.stack([_jitter(s, n, self.height * self.ss[0]) for s in seeds])
        xi = jnp.stack([_strata(s, n, self.edge_samples) for s in seeds])
        while True:
            fn = _loss_fn(vertex_fn, self.width, self.height, self.ss, budget, self.edge_samples, True)
            loss, grad, needed = fn(zj, _tables(groups.tobytes(), len(groups)), targets, jnp.asarray(self.w2c),
                                    self.focal, jitter, xi)
            needed = int(np.max(needed))
            if needed <= budget:
                break
            budget = self._grown(key, needed)
        grad = np.nan_to_num(np.asarray(grad, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        return np.asarray(loss, np.float64), grad


def _round_up(n: int) -> int:
    """``n`` rounded up to one of 8 sizes per octave (at most 12.5 % more work than asked for)."""
    step = max(1 << max(int(n).bit_length() - 4, 0), 1)
    return -(-int(n) // step) * step


def _single_group(faces) -> np.ndarray:
    """The one face group of ``faces`` (an array, or a list of one); two groups (a class mask) are refused."""
    if isinstance(faces, (list, tuple)):
        if len(faces) > 1:
            raise UserError("the jax renderer draws silhouettes only; a class-mask term (window masks) "
                            "needs the mitsuba renderer")
        faces = faces[0]
    return np.ascontiguousarray(np.asarray(faces, np.int32).reshape(-1, 3))


def _jitter(seed: int, n_views: int, rows: int) -> jnp.ndarray:
    """Sample-grid jitter (n, rows, 2) in [0, 1) per view and sample row for render ``seed``
    (:func:`coverage`)."""
    return jnp.asarray(np.random.default_rng([int(seed), 7]).random((n_views, rows, 2)), jnp.float32)


def _strata(seed: int, n_views: int, n: int) -> jnp.ndarray:
    """Stratification jitter (n_views, n) in [0, 1) of the edge samples for render ``seed``."""
    return jnp.asarray(np.random.default_rng([int(seed), 11]).random((n_views, n)), jnp.float32)


@lru_cache(maxsize=64)
def _tables(face_bytes: bytes, n_faces: int):
    faces = np.frombuffer(face_bytes, np.int32).reshape(n_faces, 3)
    edges, opposite = edge_table(faces)
    return jnp.asarray(faces), jnp.asarray(edges), jnp.asarray(opposite)


@lru_cache(maxsize=64)
def _render_fn(width: int, height: int, ss: int, budget: int):
    """jit(vertices, faces, w2c, focal, jitter) -> (pixel areas (n, H, W), spans needed per view)."""

    def fn(vertices, faces, w2c, focal, jitter):
        cov, needed = jax.vmap(lambda m, o: render_view(vertices, m, focal, faces, width, height, ss, o, budget))(
            w2c, jitter)
        return jax.vmap(lambda c: pixel_area(c, ss))(cov), needed

    return jax.jit(fn)


@lru_cache(maxsize=64)
def _loss_fn(vertex_fn: Callable, width: int, height: int, ss: int, budget: int, n_samples: int,
             batched: bool = False):
    """jit(z, tables, targets, w2c, focal, jitter, xi) -> (loss, d loss / d z, spans needed per
    view); ``tables`` = (faces, edges, opposite) of :func:`_tables` (arguments, not constants: XLA
    would fold them into the program at every compilation). ``batched``: over a leading axis of
    ``z``, ``jitter`` and ``xi`` (individuals of one topology)."""

    def surrogate(z, tables, targets, w2c, focal, jitter, xi):
        faces, edges, opposite = tables
        vertices = vertex_fn(z).reshape(-1, 3)
        n_views = len(targets)

        def view(m, target, o, x):
            xy, front = project(vertices, m, focal, width, height)
            face_ok = front[faces].all(1)
            cov, needed = coverage(jax.lax.stop_gradient(xy) * jnp.asarray(ss[::-1], xy.dtype), faces, face_ok, o,
                                   width * ss[1], budget)
            residual = pixel_area(cov, ss) - target
            pixel_grad = 2.0 * residual / residual.size / n_views
            sur = edge_surrogate(xy, front, cov, pixel_grad, edges, opposite, ss, x, n_samples)
            return jnp.mean(residual**2) / n_views, sur, needed

        loss, sur, needed = jax.vmap(view)(w2c, targets, jitter, xi)
        return jnp.sum(sur), (jnp.sum(loss), needed)

    def fn(z, tables, targets, w2c, focal, jitter, xi):
        (_, (loss, needed)), grad = jax.value_and_grad(surrogate, has_aux=True)(z, tables, targets, w2c, focal,
                                                                                jitter, xi)
        return loss, grad, needed

    if batched and jax.default_backend() == "cpu":  # one after another in one program: XLA's CPU
        single = fn  # scatters with a batch dimension cost more than the individuals one by one

        def fn(z, tables, targets, w2c, focal, jitter, xi):
            return jax.lax.map(lambda a: single(a[0], tables, targets, w2c, focal, a[1], a[2]), (z, jitter, xi))
    elif batched:
        fn = jax.vmap(fn, in_axes=(0, None, None, None, None, 0, 0))
    return jax.jit(fn)
