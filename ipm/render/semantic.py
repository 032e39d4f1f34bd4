"""Semantic label images of part-labelled meshes: 0 background, 1 + part label (``docs/design``,
"Semantic label images").

Two renderers of the same images, for two jobs:

- :func:`render_labels` (Mitsuba, for references): every part is an area emitter of its own
  colour (part 0 red, part 1 green, part 2 blue; more parts in further passes) and nothing else
  lights the scene, so a pixel's value is the
  share of it covered by each part's closest visible surface (box filter). The pixel is object
  when the parts together cover more than half of it, and then takes the label of the part that
  covers most of it (the majority rule of :func:`majority_labels`).
- :func:`raycast_labels` (open3d, for the genetic search's thousands of evaluations): the
  closest hit of one ray per pixel centre (or ``supersample`` x ``supersample`` stratified rays,
  combined by the same majority rule), label = the hit triangle's part label + 1. No Mitsuba:
  one call builds an Embree BVH and casts all rays (about 25 ms for a 50k-triangle tree at
  128 px on one core, most of it the BVH).

For trees (``ipm.generators.trees``: part 0 branch, part 1 foliage) the labels are those of
``ipm.io.semantic``: 1 branch, 2 foliage. :class:`LabelCaster` keeps one BVH for several
cameras and image windows (the search's impostors, :func:`pixel_rays` with ``window``).
"""
from __future__ import annotations

import numpy as np

from ipm.errors import UserError
from ipm.render.cameras import sensor_dict

INVALID = np.iinfo(np.uint32).max
"""open3d's primitive id of a ray that hit nothing."""


TREE_COLOURS = np.array([[0.30, 0.17, 0.08], [0.16, 0.45, 0.10]])
"""Mean diffuse colour of branches (brown) and foliage (green) in :func:`render_tree_rgb`
(varied per face: :func:`tree_colours`): both fall in the bands of
``ipm.io.semantic.labels_from_rgb`` (brown hue 22 deg, green hue 102 deg) in light and in shadow."""


def _as_c2w(c2w) -> np.ndarray:
    c2w = np.asarray(c2w, np.float64)
    if c2w.shape == (4, 4):
        c2w = c2w[None]
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
        raise UserError(f"camera-to-world matrices must have shape (n, 4, 4), got {c2w.shape}")
    return c2w


def _check_mesh(vertices, faces, face_labels, n_parts: int | None = None):
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    lab = np.zeros(len(f), np.int64) if face_labels is None else np.asarray(face_labels, np.int64).ravel()
    if len(lab) != len(f):
        raise UserError(f"{len(lab)} face labels for {len(f)} faces")
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise UserError("face indices out of range")
    if len(lab) and (lab.min() < 0 or lab.max() > 253 or (n_parts is not None and lab.max() >= n_parts)):
        raise UserError(f"part labels must be in 0..{(n_parts or 254) - 1}, got {lab.min()}..{lab.max()}")
    if not np.all(np.isfinite(v)):
        raise UserError("mesh has non-finite vertices")
    return v, f, lab


def majority_labels(coverage: np.ndarray) -> np.ndarray:
    """Labels from per-part coverage (..., P) in [0, 1]: background unless the parts cover more
    than half of the pixel, else 1 + the part that covers most (ties: the lower part)."""
    coverage = np.asarray(coverage, np.float64)
    obj = coverage.sum(-1) > 0.5
    return np.where(obj, np.argmax(coverage, -1) + 1, 0).astype(np.uint8)


def downsample_labels(labels: np.ndarray, factor: int, n_parts: int = 2) -> np.ndarray:
    """Label images (..., H, W) reduced by an integer ``factor`` with the majority rule of
    :func:`majority_labels` over each ``factor`` x ``factor`` block (H, W multiples of it)."""
    labels = np.asarray(labels)
    if factor == 1:
        return labels.astype(np.uint8)
    *lead, h, w = labels.shape
    if h % factor or w % factor:
        raise UserError(f"a {w}x{h} label image cannot be reduced by {factor}")
    blocks = labels.reshape(*lead, h // factor, factor, w // factor, factor)
    cov = np.stack([(blocks == p + 1).mean(axis=(-3, -1)) for p in range(n_parts)], -1)
    return majority_labels(cov)


def resample_labels(labels: np.ndarray, window, out_size, n_parts: int = 2) -> np.ndarray:
    """The region ``window`` = (x0, y0, x1, y1) (pixels, may reach past the borders, where it is
    background) of a label image (H, W), resampled to ``out_size`` = (W', H') pixels: per-part
    coverage by area averaging (box filter), then the majority rule of :func:`majority_labels`."""
    from PIL import Image

    labels = np.asarray(labels)
    h, w = labels.shape
    x0, y0, x1, y1 = map(float, window)
    pad = int(np.ceil(max(0.0, -x0, -y0, x1 - w, y1 - h)))
    box = (x0 + pad, y0 + pad, x1 + pad, y1 + pad)
    cov = []
    for p in range(n_parts):
        layer = np.zeros((h + 2 * pad, w + 2 * pad), np.float32)
        layer[pad:pad + h, pad:pad + w] = labels == p + 1
        img = Image.fromarray(layer, mode="F").resize(tuple(map(int, out_size)), Image.BOX, box=box)
        cov.append(np.asarray(img, np.float32))
    return majority_labels(np.stack(cov, -1))


def pixel_rays(c2w, fov_x: float, width: int, height: int, window=None, out_size=None,
               supersample: int = 1) -> np.ndarray:
    """Rays (n, H, W, s*s, 6) float32 (origin, unit direction) through pixels of each camera.

    Parameters
    ----------
    c2w
        (n, 4, 4) or (4, 4) OpenGL camera-to-world matrices (principal point at the centre).
    fov_x, width, height
        The cameras' horizontal field of view (radians) and image size in pixels.
    window
        Optional ``(x0, y0, x1, y1)`` in pixels of the full image (any floats, may reach past its
        borders): the rays cover only that region, sampled at ``out_size`` = (W, H) pixels (an
        impostor). Default: the whole image at ``width`` x ``height``.
    supersample
        ``s``: rays per pixel per axis, stratified (centres of an ``s`` x ``s`` grid); 1 = the
        pixel centre.
    """
    c2w = _as_c2w(c2w)
    x0, y0, x1, y1 = (0.0, 0.0, float(width), float(height)) if window is None else map(float, window)
    out_w, out_h = (int(width), int(height)) if out_size is None else map(int, out_size)
    s = int(supersample)
    if s < 1 or out_w < 1 or out_h < 1 or not (x1 > x0 and y1 > y0):
        raise UserError("pixel_rays needs supersample >= 1, a positive output size and a non-empty window")
    sub = (np.arange(s) + 0.5) / s
    px = x0 + (np.arange(out_w)[:, None] + sub[None, :]).ravel() * (x1 - x0) / out_w  # (W s)
    py = y0 + (np.arange(out_h)[:, None] + sub[None, :]).ravel() * (y1 - y0) / out_h  # (H s)
    f = 0.5 * width / np.tan(0.5 * fov_x)
    dx = (px - width / 2) / f
    dy = -(py - height / 2) / f
    d_cam = np.stack(np.broadcast_arrays(dx[None, :], dy[:, None], -np.ones((1, 1))), -1)  # (H s, W s, 3)
    d_cam = d_cam.reshape(out_h, s, out_w, s, 3).transpose(0, 2, 1, 3, 4).reshape(out_h, out_w, s * s, 3)
    d = np.einsum("nij,hwkj->nhwki", c2w[:, :3, :3], d_cam)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    rays = np.empty(d.shape[:-1] + (6,), np.float32)
    rays[..., :3] = c2w[:, None, None, None, :3, 3]
    rays[..., 3:] = d
    return rays


class LabelCaster:
    """Closest-hit part labels of one mesh by open3d ray casting (one BVH for many casts)."""

    def __init__(self, vertices, faces, face_labels=None, n_parts: int = 2, nthreads: int = 1):
        import open3d as o3d

        v, f, lab = _check_mesh(vertices, faces, face_labels, n_parts)
        self.n_parts, self.nthreads = n_parts, int(nthreads)
        self._lut = np.append(lab + 1, 0).astype(np.uint8)  # INVALID -> index len(f) -> background
        self._n_faces = len(f)
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        if len(f):
            self._scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),
                                      o3d.core.Tensor(np.ascontiguousarray(f, np.uint32)))

    def hits(self, rays: np.ndarray) -> np.ndarray:
        """Label (0 background, 1 + part) of each ray's closest hit, shape ``rays.shape[:-1]``."""
        import open3d as o3d

        if self._n_faces == 0:
            return np.zeros(rays.shape[:-1], np.uint8)
        ans = self._scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)), nthreads=self.nthreads)
        ids = ans["primitive_ids"].numpy().astype(np.int64)
        ids[ids == INVALID] = self._n_faces
        return self._lut[ids]

    def silhouettes(self, rays: np.ndarray) -> np.ndarray:
        """Object masks (bool) from :func:`pixel_rays` output (..., H, W, k, 6): more than half of a
        pixel's k rays hit a triangle, as :meth:`labels` ``> 0`` decides; by any-hit tests."""
        import open3d as o3d

        if self._n_faces == 0 or rays.size == 0:
            return np.zeros(rays.shape[:-2], bool)
        hit = self._scene.test_occlusions(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)),
                                          nthreads=self.nthreads).numpy()
        return 2 * np.count_nonzero(hit, axis=-1) > hit.shape[-1]

    def labels(self, rays: np.ndarray) -> np.ndarray:
        """Label images from :func:`pixel_rays` output (..., H, W, k, 6): majority over the k rays."""
        hit = self.hits(rays)
        if hit.shape[-1] == 1:
            return hit[..., 0]
        cov = np.stack([(hit == p + 1).mean(-1) for p in range(self.n_parts)], -1)
        return majority_labels(cov)


def raycast_labels(vertices, faces, face_labels, c2w, fov_x: float, width: int, height: int, *,
                   supersample: int = 1, n_parts: int = 2, nthreads: int = 1) -> np.ndarray:
    """Label images (n, height, width) uint8 of a part-labelled mesh by open3d ray casting.

    Closest hit per ray; label = part label + 1 (trees: 1 branch, 2 foliage), 0 where no
    triangle is hit. ``supersample`` > 1 casts that many rays per pixel and axis and applies the
    majority rule of :func:`majority_labels` (as :func:`render_labels` does with coverage).
    """
    caster = LabelCaster(vertices, faces, face_labels, n_parts, nthreads)
    return caster.labels(pixel_rays(c2w, fov_x, width, height, supersample=supersample))


def _emitter_mesh(name: str, v: np.ndarray, f: np.ndarray, colour):
    import mitsuba as mi

    props = mi.Properties()
    props["emitter"] = mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": [float(c) for c in colour]}})
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}})
    mesh = mi.Mesh(name, len(v), len(f), props=props)
    mp = mi.traverse(mesh)
    mp["vertex_positions"] = mi.Float(np.ascontiguousarray(v, np.float32).ravel())
    mp["faces"] = mi.UInt32(np.ascontiguousarray(f, np.uint32).ravel())
    mp.update()
    return mesh


def render_labels(vertices, faces, face_labels, c2w, fov_x: float, width: int, height: int,
                  spp: int = 64, n_parts: int | None = None) -> np.ndarray:
    """Label images (n, height, width) uint8 rendered with Mitsuba (rule: module docstring).

    Each part becomes one mesh with a black BSDF; in each pass up to three parts are area emitters
    of a unit colour (``PART_EMISSION`` and blue) and the others only occlude, and a path tracer of
    depth 1 (only directly visible emission) makes a pixel's channels those parts' coverages:
    trees (two parts) take one pass, buildings' four classes two. The mesh must be closed and
    wound outwards (Mitsuba's area emitters are one-sided). Needs a Mitsuba variant set by the
    entry point (``ipm.runtime.set_mitsuba_variant``).
    """
    import mitsuba as mi

    v, f, lab = _check_mesh(vertices, faces, face_labels, n_parts)
    n_parts = int(lab.max(initial=0)) + 1 if n_parts is None else int(n_parts)
    c2w = _as_c2w(c2w)
    sensors = {f"sensor_{i:03d}": sensor_dict(m, fov_x, width, height) for i, m in enumerate(c2w)}
    coverage = np.zeros((len(c2w), height, width, n_parts))
    for first in range(0, n_parts, 3):
        scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 1}, **sensors}
        for p in range(n_parts):
            sel = f[lab == p]
            if len(sel) == 0:
                continue
            colour = np.eye(3)[p - first] if first <= p < first + 3 else np.zeros(3)
            used, inv = np.unique(sel, return_inverse=True)
            scene[f"part_{p}"] = _emitter_mesh(f"part_{p}", v[used], inv.reshape(-1, 3), colour)
        scene = mi.load_dict(scene)
        last = min(first + 3, n_parts)
        for i in range(len(c2w)):
            img = np.array(mi.render(scene, sensor=i, spp=spp, seed=i))
            coverage[i, ..., first:last] = np.clip(img[..., :last - first], 0.0, 1.0)
    return majority_labels(coverage)


def tree_colours(face_labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """Diffuse colour (F, 3) of each face of a tree: ``TREE_COLOURS`` varied per face (seeded),
    bark over browns of shifting darkness and leaves each its own green (hue 80-125 degrees,
    lighter and darker), as a photographed tree shows, not two flat colours. Every colour stays
    in the bands ``ipm.io.semantic.labels_from_rgb`` reads."""
    from skimage.color import hsv2rgb, rgb2hsv

    rng = np.random.default_rng(seed)
    lab = np.asarray(face_labels)
    hsv = rgb2hsv(TREE_COLOURS[lab][:, None, :])[:, 0]
    leaf = lab == 1
    hsv[:, 0] += np.where(leaf, rng.uniform(-22, 23, len(lab)), rng.uniform(-8, 8, len(lab))) / 360.0
    hsv[:, 1] *= np.where(leaf, rng.uniform(0.7, 1.15, len(lab)), rng.uniform(0.7, 1.2, len(lab)))
    hsv[:, 2] *= np.where(leaf, rng.uniform(0.6, 1.5, len(lab)), rng.uniform(0.55, 1.35, len(lab)))
    return hsv2rgb(np.clip(hsv, 0.0, 1.0)[:, None, :])[:, 0]


def render_tree_rgb(vertices, faces, face_labels, c2w, fov_x: float, width: int, height: int,
                    spp: int = 32, seed: int = 0) -> np.ndarray:
    """Linear RGB renders (n, height, width, 3) of a tree, its bark and leaves in varied browns
    and greens (:func:`tree_colours`), under the reference lighting of ``ipm.render.textured``."""
    import mitsuba as mi

    from ipm.render.textured import _render_lit

    v0, f0, lab = _check_mesh(vertices, faces, face_labels, len(TREE_COLOURS))
    v = v0[f0].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    colours = np.repeat(tree_colours(lab, seed), 3, axis=0)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "twosided", "bsdf": {
        "type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}}})
    mesh = mi.Mesh("object", len(v), len(f), props=props)
    mesh.add_attribute("vertex_color", 3, mi.Float(colours.astype(np.float32).ravel()))
    return _render_lit(mesh, v, f, _as_c2w(c2w), fov_x, width, height, spp)
