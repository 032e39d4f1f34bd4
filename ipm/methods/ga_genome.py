"""The genetic path's genome: a generator's parameters and four pose genes, decoded to a world mesh.

The generator's parameters in the unit cube (``generator.spec``) are followed by four pose genes
(:data:`POSE_GENES`), all in [0, 1]:

- ``pose_yaw``: rotation about +y, ``2 pi u``;
- ``pose_lateral``, ``pose_depth``: offsets of the object's base along the input camera's right
  and forward directions projected onto the ground, ``(2 u - 1) * LATERAL`` (``DEPTH``) times the
  anchor height (plants, ``Generator.plant``; ``OTHER_OFFSETS`` for others), around the anchor of
  :func:`anchor` (ground contact and height from the first view's mask);
- ``pose_scale``: the object's world height relative to the anchor height, log-uniform over
  ``SCALE_RANGE``.

The generated mesh (lowest point moved to y = 0) is scaled to that height, turned and set down on
y = 0 at the offset anchor: the output is in the world frame of the views, its pose written as
the differentiable path writes its own (``ipm.pose``, tilts 0). (The trees generator's own
``height`` parameter is therefore inert here; its statistics give it a near-zero mutation rate.)
"""
from __future__ import annotations

import math

import numpy as np

from ipm.errors import UserError
from ipm.generators.base import Generator, Mesh, make_spec, vertex_normals
from ipm.io.views import Views
from ipm.pose import POSE_KEYS, yaw_matrix

POSE_GENES = ("pose_yaw", "pose_lateral", "pose_depth", "pose_scale")
"""Names of the pose genes appended to the generator's parameters."""
LATERAL = 0.03
"""Half range of the sideways offset of the base, in anchor heights (the anchor's column is the
base's own)."""
DEPTH = 0.03
"""Half range of the offset of the base along the view direction, in anchor heights. One view
barely sees depth (a tree 5 % of its height further away is 2 % smaller in the image), so the
search trades it for outline details when it may: with a range of 0.25 (0.1) a poplar fit stood
0.12 (0.09) off along the ray, invisible in the input view, at 64-view IoU 0.47 (0.63) where its
shape alone was worth 0.8. The anchor's ground contact (the trunk's lowest pixel, pushed back by
half the trunk's width) is the better depth cue, so the genes only absorb its pixel error."""
SCALE_RANGE = (0.8, 1.25)
"""World height of the object relative to the anchor height (log-uniform gene)."""
OTHER_OFFSETS = (0.1, 0.2)
"""(lateral, depth) half ranges for generators other than plants: the anchor of a cup is pushed
back from its front contact by half the width just above the base, a rougher guess than a trunk's."""


def _ground_axes(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera's right and forward directions projected onto the ground plane (unit)."""
    right, fwd = c2w[:3, 0].copy(), -c2w[:3, 2].copy()
    right[1] = fwd[1] = 0.0
    if np.linalg.norm(fwd) < 1e-6:  # looking straight down: forward = image up
        fwd = c2w[:3, 1].copy()
        fwd[1] = 0.0
    right /= max(np.linalg.norm(right), 1e-12)
    fwd /= max(np.linalg.norm(fwd), 1e-12)
    return right, fwd


def anchor(views: Views, plant: bool) -> tuple[np.ndarray, float]:
    """Ground position (x, 0, z) and height of the object from the first view's mask.

    :func:`ipm.problem.estimate_anchor`, except that for plants the height is measured again,
    without that function's bound of 20 half-widths of the mask just above the base (a tree's
    thin trunk makes the bound far too low: 0.55 for a 1.5 tall tree): the top mask row's ray,
    at its closest approach to the vertical through the ground position.
    """
    from ipm.problem import estimate_anchor
    from ipm.render.cameras import pixel_ray, project

    centre, height = estimate_anchor(views)
    if not plant:
        return centre, height
    mask, c2w = views.masks[0], views.c2w[0]
    h, w = mask.shape
    top = int(np.nonzero(mask.max(1) > 0.5)[0].min())
    px = float(project(centre[None], c2w, views.fov_x, w, h)[0, 0])
    origin, d = pixel_ray(px, float(top), c2w, views.fov_x, w, h)
    horiz = np.array([d[0], 0.0, d[2]])
    s = np.dot(centre - origin, horiz) / max(np.dot(horiz, horiz), 1e-9)
    height = float(origin[1] + s * d[1])
    if not np.isfinite(height) or height <= 0:
        raise UserError("cannot estimate the tree's height from the input mask")
    return centre, height


class Genome:
    """Unit-cube genomes -> world meshes: the generator's parameters plus :data:`POSE_GENES`."""

    def __init__(self, generator: Generator, anchor_t: np.ndarray, anchor_h: float, c2w0: np.ndarray):
        self.generator = generator
        gspec = generator.spec
        rows = [(n, lo, hi, bool(d), v) for n, lo, hi, d, v in
                zip(gspec.names, gspec.lower, gspec.upper, gspec.discrete, gspec.default)]
        rows += [(n, 0.0, 1.0, False, 0.5) for n in POSE_GENES]
        self.spec = make_spec(rows)
        self.n_shape = len(gspec)
        self.anchor_t = np.array([anchor_t[0], 0.0, anchor_t[2]], np.float64)
        self.anchor_h = float(anchor_h)
        self.right, self.fwd = _ground_axes(np.asarray(c2w0, np.float64))
        self.lateral, self.depth = (LATERAL, DEPTH) if generator.plant else OTHER_OFFSETS

    def params(self, g: np.ndarray) -> np.ndarray:
        """Physical generator parameters of genome ``g`` (the unit cube mapped into the generator's
        bounds, discrete ones rounded)."""
        gspec = self.generator.spec
        u = np.asarray(g, np.float64)[: self.n_shape]
        return gspec.from_unit(u)

    def pose(self, g: np.ndarray) -> tuple[float, np.ndarray, float]:
        """Yaw (radians), base position (x, 0, z) and world height of genome ``g``."""
        p = np.clip(np.asarray(g, np.float64)[self.n_shape:], 0.0, 1.0)
        yaw = 2.0 * math.pi * p[0]
        base = (self.anchor_t + (2 * p[1] - 1) * self.lateral * self.anchor_h * self.right
                + (2 * p[2] - 1) * self.depth * self.anchor_h * self.fwd)
        lo, hi = np.log(SCALE_RANGE)
        height = self.anchor_h * math.exp(lo + p[3] * (hi - lo))
        return yaw, base, height

    def object_mesh(self, x: np.ndarray, lod: int, uv: bool = True):
        """The generator's mesh in its own frame and, for plants, its branch-graph size; ``uv=False``
        may leave a plant's texture charts out."""
        if self.generator.plant:
            mesh, graph = self.generator.generate(x, lod, uv)
            return mesh, graph.n_vertices
        return self.generator.mesh(x, lod), None

    def place(self, g: np.ndarray, mesh: Mesh) -> tuple[np.ndarray, float, np.ndarray, float]:
        """World vertices of ``mesh`` placed by genome ``g``, and the pose as (yaw, scale,
        translation): ``world = scale * R_y(yaw) v + translation``."""
        yaw, base, height = self.pose(g)
        v = mesh.vertices
        lo, hi = float(v[:, 1].min()), float(v[:, 1].max())
        scale = height / max(hi - lo, 1e-9)
        trans = base - np.array([0.0, scale * lo, 0.0])
        return scale * v @ yaw_matrix(yaw).T + trans, scale, trans, yaw

    def world_mesh(self, g: np.ndarray, lod: int) -> tuple[Mesh, dict]:
        """The placed mesh (world frame) and its description for params.json."""
        x = self.params(g)
        mesh, n_graph = self.object_mesh(x, lod)
        v, scale, trans, yaw = self.place(g, mesh)
        out = Mesh(v, mesh.faces, vertex_normals(v, mesh.faces), mesh.uv, mesh.labels, mesh.part_names)
        info = {"generator": self.generator.name, "params": self.generator.spec.as_dict(x),
                "pose": dict(zip(POSE_KEYS, (yaw, 0.0, 0.0, trans.tolist(), scale))),
                "genes": {n: float(u) for n, u in zip(self.spec.names, g)}}
        if n_graph is not None:
            info["branch_graph_vertices"] = int(n_graph)
        return out, info
