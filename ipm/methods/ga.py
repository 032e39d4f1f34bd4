"""The genetic path (paper, "Non-differentiable Case"): the tree of elementary GAs over generator
parameters and pose, fitted to one view (or a few) by ray-cast impostors.

**Genome.** The generator's parameters in the unit cube (``generator.spec``) followed by four
pose genes (:data:`POSE_GENES`), all in [0, 1]:

- ``pose_yaw``: rotation about +y, ``2 pi u``;
- ``pose_lateral``, ``pose_depth``: offsets of the object's base along the input camera's right
  and forward directions projected onto the ground, ``(2 u - 1) * LATERAL`` (``DEPTH``) times the
  anchor height (trees; ``OTHER_OFFSETS`` for others), around the anchor of :func:`anchor`
  (ground contact and height from the first view's mask);
- ``pose_scale``: the object's world height relative to the anchor height, log-uniform over
  ``SCALE_RANGE``.

The generated mesh (lowest point moved to y = 0) is scaled to that height, turned and set down on
y = 0 at the offset anchor: the output is in the world frame of the views. (The trees generator's
own ``height`` parameter is therefore inert here; its statistics give it a near-zero mutation
rate.)

**Impostors.** Each input view's reference is cut to a square window around the object's pixel
bounding box (``margin`` on every side) and resampled to ``impostor`` pixels (area coverage per
part, then the majority rule: ``ipm.render.semantic.resample_labels``); a candidate is ray cast
(open3d, closest hit) through the same window at the same size, so both images are aligned pixel
for pixel and the object fills most of the impostor whatever the photo's size (the authors'
impostors are 256 px; ``default`` uses 128 px, see :data:`PROFILE_OPTIONS`).

**Loss** (:class:`Objective`). Trees (generators with parts ``branch`` and ``foliage``): the
paper's ``1 - TSim * prod(multipliers)`` (``ipm.losses.tree``; 16 stripes over the object's
height, as on the authors' 256 px impostors with 16 px stripes) with the multipliers named in
``regularisers`` (default: leaf density, one of the paper's "average branches and leaves
density"; ``graph_vertices=N`` adds the paper's recommended branch-graph size regulariser with
target ``N``) and three of ours: the silhouette IoU in the input view (``placement``: TSim cannot
see the pose), the silhouette IoU of the candidate turned about its axis (``turns``: a round crown
rather than a fan seen edge-on) and a complexity budget (``max_graph_vertices``). Other generators
(the dishes ablation): ``1 - IoU`` of the silhouettes. The loss is the mean over the input views.

**Statistics** (the paper's ``V(k)``, ``P_ij``, ``Q_ij``): gathered per generator on random
genomes against a family of canonical references (each preset of the generator seen from a
near-horizontal camera with a known anchor), so one JSON file serves every case:
:func:`collect_generator_statistics` (a cached pipeline stage), or collected by :func:`run_ga`
itself when no file is given, at ``2 * stats_samples`` evaluations (``default``: 2000).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.generators.base import Generator, Mesh, make_spec, vertex_normals
from ipm.io import load_views, shown_path
from ipm.io.views import Views
from ipm.methods.results import write_result
from ipm.optim.ga import GASettings, GeneStatistics, TreeGA, collect_statistics, get_settings
from ipm.render.cameras import orbit_camera

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
"""(lateral, depth) half ranges for generators other than trees: the anchor of a cup is pushed
back from its front contact by half the width just above the base, a rougher guess than a trunk's."""
TREE_PARTS = ("branch", "foliage")
"""Part names of generators fitted with the tree loss."""


@dataclass(frozen=True)
class GAOptions:
    """Settings of the GA path's objective (the GA's own settings: ``ipm.optim.ga.GASettings``)."""

    impostor: int = 128
    """Impostor size in pixels (square)."""
    margin: float = 0.12
    """Space around the reference's bounding box in the impostor window, per side, as a share of
    the box's longer side."""
    supersample: int = 1
    """Rays per impostor pixel and axis (majority rule beyond 1)."""
    n_stripes: int = 16
    """Stripes of the tree similarity (over the object's height)."""
    regularisers: tuple[str, ...] = ("leaf_density",)
    """Multipliers of ``ipm.losses.tree`` (trees). ``branch_density`` is left out by default: a
    crowned tree shows a few dozen branch pixels, and their ratio is noise (0.67-0.81 for the true
    tree_2 and copies of it with one unrelated gene changed)."""
    graph_vertices: int | None = None
    """Target branch-graph vertex count (the paper's recommended regulariser); None: off."""
    placement: str = "mask"
    """Multiplier that sees the pose (trees): ``mask`` (IoU of the reference's and the candidate's
    silhouettes in the input view), ``box`` (IoU of their pixel bounding boxes) or ``none``."""
    turns: int = 4
    """Views of a tree around its vertical axis (1: the input view only; :class:`Objective`)."""
    turn_weight: float = 1.0
    """``w`` of the symmetry multiplier ``1 - w (1 - s)``, ``s`` the turned views' mean IoU."""
    max_graph_vertices: int | None = 4000
    """Complexity budget (trees): multiply by ``min(1, max_graph_vertices / n)`` for a branch graph
    of ``n`` vertices. Without it the search drifts to the most complex trees the generator makes
    (a tree_1 run ended at 46k graph vertices, 1.5M triangles at the output's detail, 112 ms per
    evaluation), as the paper warns; 4000 is above every preset (700-2700). None: off."""
    lod: int = 0
    """Generator level of detail during the search."""
    output_lod: int | None = None
    """Level of detail of the written mesh; None: ``lod`` for trees (the trees generator's turtle
    takes more sub-steps at finer levels, which can reshape a tree with strong curvature: a fit
    0.4 wide at level 0 was 1.4 wide at level 2), 1 for others (as the differentiable path)."""
    loss: str = "auto"
    """``tree``, ``silhouette`` or ``auto`` (tree for generators with branch and foliage parts)."""
    labels: str = "auto"
    """Where the tree loss's reference labels come from: ``semantic`` (the views' label images),
    ``rgb`` (the photos' colours inside the masks, ``ipm.io.semantic.labels_from_rgb``, as the
    paper does in simple cases) or ``auto`` (label images where the views have them)."""

    def __post_init__(self):
        if self.loss not in ("auto", "tree", "silhouette"):
            raise UserError(f"unknown GA loss {self.loss!r} (known: auto, tree, silhouette)")
        if self.labels not in ("auto", "semantic", "rgb"):
            raise UserError(f"unknown GA labels {self.labels!r} (known: auto, semantic, rgb)")
        if int(self.impostor) != self.impostor or self.impostor < 16:
            raise UserError(f"impostor must be an integer >= 16 pixels, got {self.impostor!r}")
        if int(self.supersample) != self.supersample or self.supersample < 1:
            raise UserError(f"supersample must be a positive integer, got {self.supersample!r}")
        if self.placement not in ("mask", "box", "none"):
            raise UserError(f"unknown placement {self.placement!r} (known: mask, box, none)")
        if int(self.turns) != self.turns or self.turns < 1 or not 0.0 <= self.turn_weight <= 1.0:
            raise UserError(f"turns must be a positive integer and turn_weight in [0, 1], got "
                            f"{self.turns!r} and {self.turn_weight!r}")
        if not 0.0 <= self.margin <= 1.0:
            raise UserError(f"margin must be in [0, 1], got {self.margin!r}")
        for name in ("graph_vertices", "max_graph_vertices"):
            v = getattr(self, name)
            if v is not None and (int(v) != v or v < 1):
                raise UserError(f"{name} must be a positive integer or None, got {v!r}")


PROFILE_OPTIONS = {
    "smoke": GAOptions(impostor=64, n_stripes=8),
    "default": GAOptions(),
    "paper": GAOptions(impostor=256),
}
"""Objective settings per profile (the GA's budget comes from ``ipm.optim.ga.GA_PROFILES``)."""


def get_options(profile: str, **overrides) -> GAOptions:
    """The profile's objective settings with ``overrides`` (``UserError`` for unknown names)."""
    if profile not in PROFILE_OPTIONS:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(PROFILE_OPTIONS)})")
    known = set(GAOptions.__dataclass_fields__)
    bad = sorted(set(overrides) - known)
    if bad:
        raise UserError(f"unknown GA option(s) {', '.join(bad)} (known: {', '.join(sorted(known))})")
    if "regularisers" in overrides and overrides["regularisers"] is not None:
        overrides["regularisers"] = tuple(overrides["regularisers"])
    return replace(PROFILE_OPTIONS[profile], **overrides)


# ----------------------------------------------------------------------------------------------
# Genome: generator parameters + pose


def _yaw_matrix(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


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


def anchor(views: Views, tree: bool) -> tuple[np.ndarray, float]:
    """Ground position (x, 0, z) and height of the object from the first view's mask.

    :func:`ipm.problem.estimate_anchor`, except that for trees the height is measured again,
    without that function's bound of 20 half-widths of the mask just above the base (a tree's
    thin trunk makes the bound far too low: 0.55 for a 1.5 tall tree): the top mask row's ray,
    at its closest approach to the vertical through the ground position.
    """
    from ipm.problem import estimate_anchor
    from ipm.render.cameras import pixel_ray, project

    centre, height = estimate_anchor(views)
    if not tree:
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
        self.tree = generator.part_names == TREE_PARTS
        self.lateral, self.depth = (LATERAL, DEPTH) if self.tree else OTHER_OFFSETS

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

    def object_mesh(self, x: np.ndarray, lod: int):
        """The generator's mesh in its own frame and, for trees, its branch-graph size."""
        if self.tree:
            mesh, graph = self.generator.generate(x, lod)
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
        return scale * v @ _yaw_matrix(yaw).T + trans, scale, trans, yaw

    def world_mesh(self, g: np.ndarray, lod: int) -> tuple[Mesh, dict]:
        """The placed mesh (world frame) and its description for params.json."""
        x = self.params(g)
        mesh, n_graph = self.object_mesh(x, lod)
        v, scale, trans, yaw = self.place(g, mesh)
        out = Mesh(v, mesh.faces, vertex_normals(v, mesh.faces), mesh.uv, mesh.labels, mesh.part_names)
        info = {"generator": self.generator.name, "params": self.generator.spec.as_dict(x),
                "pose": {"yaw": yaw, "tilt_x": 0.0, "tilt_z": 0.0, "translation": trans.tolist(), "scale": scale},
                "genes": {n: float(u) for n, u in zip(self.spec.names, g)}}
        if n_graph is not None:
            info["branch_graph_vertices"] = int(n_graph)
        return out, info


# ----------------------------------------------------------------------------------------------
# Impostor targets and the objective


@dataclass
class Target:
    """One reference impostor: camera, window in the view's pixels and the reduced labels."""

    c2w: np.ndarray
    """Camera-to-world matrix (4, 4) of the view, OpenGL convention."""
    fov_x: float
    """Horizontal field of view of the view (radians)."""
    width: int
    """Width of the view in pixels."""
    height: int
    """Height of the view in pixels."""
    window: tuple[float, float, float, float]
    """The impostor's region of the view: (x0, y0, x1, y1) in pixels."""
    labels: np.ndarray
    """(impostor, impostor) uint8 reference labels (0 background, 1 + part)."""
    stats: object = None
    """``TreeStats`` of ``labels`` (tree loss), built once."""
    mirror: np.ndarray | None = None
    """The reference's silhouette mirrored about its root (the outline seen from behind)."""
    rays: np.ndarray = field(default=None, repr=False)
    """The impostor's rays (impostor, impostor, supersample**2, 6), cast for every candidate."""


def make_target(labels: np.ndarray, c2w: np.ndarray, fov_x: float, options: GAOptions) -> Target:
    """Cut the reference label image (H, W) to a square window around the object (``margin`` on
    each side) and resample it to ``options.impostor`` pixels (area coverage, majority rule)."""
    from ipm.render.semantic import pixel_rays, resample_labels

    labels = np.asarray(labels, np.uint8)
    h, w = labels.shape
    box = _bbox(labels)
    if box is None:
        raise UserError("the reference view has no object pixels")
    top, bottom, left, right = box
    side = max(bottom - top, right - left) * (1.0 + 2.0 * options.margin)
    cx, cy = 0.5 * (left + right), 0.5 * (top + bottom)
    window = (cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2)
    size = (options.impostor, options.impostor)
    reduced = resample_labels(labels, window, size, n_parts=max(2, int(labels.max())))
    if not reduced.any():
        raise UserError("the reference object vanishes at the impostor resolution")
    rays = pixel_rays(c2w, fov_x, w, h, window, size, options.supersample)[0]
    return Target(np.asarray(c2w), fov_x, w, h, window, reduced, rays=rays)


def _bbox(labels: np.ndarray):
    rows, cols = np.flatnonzero(labels.any(1)), np.flatnonzero(labels.any(0))
    if rows.size == 0:
        return None
    return rows[0], rows[-1] + 1, cols[0], cols[-1] + 1


def box_iou(a, b) -> float:
    """IoU of two pixel boxes (top, bottom, left, right)."""
    ih = max(0, min(a[1], b[1]) - max(a[0], b[0]))
    iw = max(0, min(a[3], b[3]) - max(a[2], b[2]))
    inter = ih * iw
    union = (a[1] - a[0]) * (a[3] - a[2]) + (b[1] - b[0]) * (b[3] - b[2]) - inter
    return inter / union if union > 0 else 0.0


def uses_tree_loss(generator: Generator, options: GAOptions) -> bool:
    """Whether ``options.loss`` picks the tree loss for ``generator`` (``UserError`` if it cannot)."""
    tree = generator.part_names == TREE_PARTS if options.loss == "auto" else options.loss == "tree"
    if tree and generator.part_names != TREE_PARTS:
        raise UserError(f"the tree loss needs a generator with parts branch and foliage, not "
                        f"{generator.name!r} ({', '.join(generator.part_names)})")
    return tree


def output_lod(generator: Generator, options: GAOptions) -> int:
    """Level of detail of the written mesh (``GAOptions.output_lod``)."""
    if options.output_lod is not None:
        return int(options.output_lod)
    return options.lod if generator.part_names == TREE_PARTS else min(1, max(generator.lods))


def _turned_rays(rays: np.ndarray, base: np.ndarray, turns: int) -> np.ndarray:
    """``rays`` (..., 6) turned about the vertical through ``base`` by ``2 pi k / turns``, k =
    0..turns-1, on a new axis after the first (turning the rays by -a shows the object turned by a)."""
    out = np.empty((rays.shape[0], turns) + rays.shape[1:], np.float32)
    o, d = rays[..., :3].astype(np.float64) - base, rays[..., 3:].astype(np.float64)
    for k in range(turns):
        rot = _yaw_matrix(-2.0 * math.pi * k / turns)
        out[:, k, ..., :3] = o @ rot.T + base
        out[:, k, ..., 3:] = d @ rot.T
    return out


class Objective:
    """Loss of genomes against impostor targets (one per input view, or a statistics family).

    Trees: ``loss = 1 - TSim * prod(regularisers) * placement * symmetry * complexity``, all
    multipliers in [0, 1] like the paper's:

    - ``placement``: silhouette IoU of candidate and reference in the input view. TSim compares
      shapes normalised to the object's height and root, so it cannot see the pose; near the true
      tree the input view's silhouette IoU also ranks candidates by their 64-view IoU far better
      than TSim (Spearman 0.97-0.98 against 0.82-0.88 over 40 perturbations of tree_1 and tree_2);
    - ``symmetry``: the candidate seen *turned* about the vertical through its base (``turns``
      views around it, through the same camera) against the reference, or its mirror image about
      the root (the outline seen from behind), whichever fits better: one view cannot tell a round
      crown from a flat fan seen edge-on, and without this prior the search finds such fans (a
      poplar fit 1.6 times too wide seen from the side, 64-view IoU 0.39). Trees look alike from
      every side;
    - ``complexity``: ``min(1, max_graph_vertices / n)``.

    Other generators (dishes): ``1 - IoU`` of the silhouettes. Empty candidates score 1.
    """

    def __init__(self, genome: Genome, targets: list[Target], options: GAOptions):
        from ipm.losses.tree import TreeStats

        self.genome, self.targets, self.options = genome, targets, options
        self.tree = tree = uses_tree_loss(genome.generator, options)
        self.turns = options.turns if tree else 1
        self.regularisers = list(options.regularisers or ())
        if tree and options.graph_vertices is not None:
            self.regularisers.append("graph_vertices")
        for t in targets:
            if tree:
                t.stats = TreeStats(t.labels, graph_vertices=options.graph_vertices)
                t.stats.features(None, options.n_stripes)  # validates and caches
                t.mirror = mirror_about(t.labels > 0, t.stats.features(None, options.n_stripes).root_x)
        self._rays = np.stack([t.rays for t in targets])
        self.evaluations = 0
        self.seconds = 0.0

    def render(self, g: np.ndarray) -> tuple[np.ndarray, int | None]:
        """Impostor labels (n_targets, turns, impostor, impostor) of genome ``g`` and its graph size."""
        from ipm.render.semantic import LabelCaster

        x = self.genome.params(g)
        mesh, n_graph = self.genome.object_mesh(x, self.options.lod)
        v = self.genome.place(g, mesh)[0]
        caster = LabelCaster(v, mesh.faces, mesh.labels, n_parts=max(2, len(mesh.part_names)))
        return caster.labels(_turned_rays(self._rays, self.genome.pose(g)[1], self.turns)), n_graph

    def losses(self, g: np.ndarray) -> np.ndarray:
        """Loss against each target, shape (n_targets,), in [0, 1]."""
        t0 = time.perf_counter()
        images, n_graph = self.render(g)
        out = np.array([self._loss(t, img, n_graph) for t, img in zip(self.targets, images)])
        self.evaluations += 1
        self.seconds += time.perf_counter() - t0
        return out

    def __call__(self, g: np.ndarray) -> float:
        return float(np.mean(self.losses(g)))

    def _loss(self, target: Target, images: np.ndarray, n_graph: int | None) -> float:
        """Loss of one target from the candidate's images (turns, H, W) (view 0 = as placed)."""
        from ipm.losses.tree import TreeStats, loss_terms

        img = images[0]
        box = _bbox(img)
        if box is None:
            return 1.0
        ref = target.labels > 0
        if not self.tree:
            return 1.0 - _iou(ref, img > 0)
        sim = 1.0 - loss_terms(target.stats, TreeStats(img, graph_vertices=n_graph), self.regularisers,
                               stripe_height=None, n_stripes=self.options.n_stripes)["loss"]
        if self.options.placement == "box":
            sim *= box_iou(_bbox(target.labels), box)
        elif self.options.placement == "mask":
            sim *= _iou(ref, img > 0)
        if self.turns > 1:
            side = np.mean([max(_iou(ref, im > 0), _iou(target.mirror, im > 0)) for im in images[1:]])
            sim *= 1.0 - self.options.turn_weight * (1.0 - side)
        if self.options.max_graph_vertices is not None and n_graph is not None:
            sim *= min(1.0, self.options.max_graph_vertices / max(n_graph, 1))
        return float(1.0 - sim)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b)) / union if union else 1.0


def mirror_about(mask: np.ndarray, x: float) -> np.ndarray:
    """``mask`` (H, W) mirrored left to right about the vertical line at column position ``x``
    (pixel centres at i + 0.5); what leaves the image is dropped."""
    h, w = mask.shape
    src = np.rint(2.0 * x - 1.0 - np.arange(w)).astype(int)  # column i shows column 2x - 1 - i
    ok = (src >= 0) & (src < w)
    out = np.zeros_like(mask)
    out[:, ok] = mask[:, src[ok]]
    return out


# ----------------------------------------------------------------------------------------------
# Statistics over a family of canonical references


CANONICAL_ELEVATION = 10.0
"""Elevation (degrees) of the statistics family's camera: near-horizontal, as tree photos are."""


def family_objective(generator: Generator, options: GAOptions) -> Objective:
    """An objective with one target per preset of ``generator``: the preset, 1 unit high, standing
    at the origin, seen from ``CANONICAL_ELEVATION`` with a known anchor (origin, height 1).
    Scored from the input view only (``turns = 1``): four presets seen from four sides cost four
    times as much, and the statistics only need to tell tree-like gene values from others."""
    from ipm.render.semantic import raycast_labels

    options = replace(options, turns=1)
    res = 2 * options.impostor
    c2w = orbit_camera(np.array([0.0, 0.5, 0.0]), 0.9 / math.sin(0.6911 / 2), 0.0, CANONICAL_ELEVATION)
    genome = Genome(generator, np.zeros(3), 1.0, c2w)
    centre = genome.spec.to_unit(genome.spec.default)
    targets = []
    for name in sorted(generator.presets):
        g = np.concatenate([generator.spec.to_unit(generator.presets[name]), centre[genome.n_shape:]])
        g[genome.n_shape] = 0.0  # yaw 0
        mesh, _ = genome.world_mesh(g, options.lod)
        labels = raycast_labels(mesh.vertices, mesh.faces, mesh.labels, c2w, 0.6911, res, res, supersample=2,
                                n_parts=max(2, len(mesh.part_names)))[0]
        targets.append(make_target(labels, c2w, 0.6911, options))
    return Objective(genome, targets, options)


def generator_statistics(generator: Generator, settings: GASettings, options: GAOptions, seed: int = 0,
                         progress: bool = False) -> GeneStatistics:
    """The paper's gene statistics of ``generator``'s genome over its family of canonical
    references (:func:`family_objective`): ``2 * settings.stats_samples`` evaluations."""
    objective = family_objective(generator, options)
    return collect_statistics(objective.genome.spec, objective.losses, settings.stats_samples, settings.bins,
                              seed=seed, progress=progress, h=settings.stats_h,
                              good_fraction=settings.good_fraction, prior=settings.stats_prior)


def collect_generator_statistics(generator: str, out_path: str | Path, profile: str = "default", seed: int = 0,
                                 progress: bool = False, **options) -> dict:
    """Pipeline stage: gene statistics of ``generator`` for the GA path, written to ``out_path``
    (JSON, atomically; load with ``GeneStatistics.load``). Cost: ``2 * stats_samples`` of the
    profile's evaluations (``default``: 2000, 2-3 minutes for trees on one core)."""
    t0 = time.perf_counter()
    gen = get_generator(generator)
    settings = get_settings(profile)
    opts = get_options(profile, **options)
    stats = generator_statistics(gen, settings, opts, seed, progress)
    stats.save(out_path)
    return {"generator": generator, "samples": stats.n_samples, "seconds": time.perf_counter() - t0}


# ----------------------------------------------------------------------------------------------
# The method


def _read_rgb(path: Path, width: int, height: int) -> np.ndarray:
    from PIL import Image

    if not path.is_file():
        raise UserError(f"RGB image not found: {path} (needed for labels_from_rgb without a semantic_path)")
    try:
        with Image.open(path) as im:
            rgb = np.asarray(im.convert("RGB"))
    except Exception as exc:
        raise UserError(f"cannot read RGB image {path}: {exc}") from None
    if rgb.shape[:2] != (height, width):
        raise UserError(f"RGB image {path} is {rgb.shape[1]}x{rgb.shape[0]}, expected {width}x{height}")
    return rgb


def reference_labels(views: Views, tree: bool, source: str = "auto") -> np.ndarray:
    """Per-view reference labels (n, H, W): for the tree loss the views' label images (``source``
    ``semantic``, or ``auto`` where they have them) or ``labels_from_rgb`` of the RGB inside the
    mask (``rgb``); for other generators the mask as label 1."""
    if not tree:
        return (views.masks > 0.5).astype(np.uint8)
    if source == "semantic" and views.semantics is None:
        raise UserError("labels: semantic, but the views have no label images (semantic_path)")
    if source != "rgb" and views.semantics is not None:
        return views.semantics
    from ipm.io.semantic import labels_from_rgb

    out = []
    for fr, mask in zip(views.frames, views.masks):
        if "file_path" not in fr:
            raise UserError("a frame has neither semantic_path nor file_path: no tree labels")
        rgb = _read_rgb(views.root / fr["file_path"], views.width, views.height)
        rgb = rgb if views.lens is None else views.lens.resample(rgb[None])[0]  # as the masks were
        out.append(labels_from_rgb(rgb, mask > 0.5))
    return np.stack(out)


def problem_objective(views: Views, generator: Generator, options: GAOptions) -> Objective:
    """The objective of a reconstruction: the genome anchored by the first view, one impostor
    target per view (checks the inputs before any search)."""
    genome = Genome(generator, *anchor(views, generator.part_names == TREE_PARTS), views.c2w[0])
    refs = reference_labels(views, uses_tree_loss(generator, options), options.labels)
    targets = [make_target(lab, c2w, views.fov_x, options) for lab, c2w in zip(refs, views.c2w)]
    return Objective(genome, targets, options)


def reconstruct(objective: Objective, settings: GASettings, stats: GeneStatistics | None, seed: int = 0,
                progress: bool = True):
    """The tree GA on ``objective``: best genome, its loss and the trace (one row per evaluation)."""
    ga = TreeGA(objective.genome.spec, settings, stats, seed=seed)
    return ga.minimize(objective, progress=progress)


def run_ga(views_path: str | Path | Views, out: str | Path, generator: str = "trees", profile: str = "default",
           seed: int = 0, progress: bool = True, n_input_views: int | None = None,
           prepared: str | Path | None = None, ga_settings: dict | None = None, **options) -> dict:
    """``ipm reconstruct --method ga``: write mesh.ply, mesh.glb, params.json, trace.csv, timing.json.

    Parameters
    ----------
    views_path, out
        ``transforms.json`` (masks; ``semantic_path`` or RGB for trees) and the output folder.
    generator, profile, seed
        Generator name, budget profile (``ipm.optim.ga.GA_PROFILES`` and :data:`PROFILE_OPTIONS`)
        and random seed (same seed, same output).
    n_input_views
        Use the first N frames (default: all); the table's row uses 1.
    prepared
        Gene statistics JSON from :func:`collect_generator_statistics` (the method's cached
        preparation stage, ``ipm prepare ga``); without it they are collected here first
        (``2 * stats_samples`` more evaluations).
    ga_settings
        Overrides of the profile's ``GASettings`` (e.g. ``{"budget": 1500}``).
    **options
        Overrides of :class:`GAOptions`; the pipeline's other keywords are ignored.
    """
    t0 = time.perf_counter()
    gen = get_generator(generator)
    settings = get_settings(profile, **(ga_settings or {}))
    opts = get_options(profile, **{k: v for k, v in options.items() if k in GAOptions.__dataclass_fields__})
    views = load_views(views_path).first(n_input_views)
    if views.camera is not None:
        raise UserError("the view's camera is unknown: the diff path estimates it (--method diff)")
    objective = problem_objective(views, gen, opts)
    t_stats = time.perf_counter()
    if prepared is not None:
        stats = GeneStatistics.load(prepared)
        stats.check(objective.genome.spec)
        stats_source = shown_path(prepared)
    else:
        stats = generator_statistics(gen, settings, opts, seed, progress)
        stats_source = "collected"
    t_stats = time.perf_counter() - t_stats
    best, loss, trace = reconstruct(objective, settings, stats, seed, progress)
    mesh, info = objective.genome.world_mesh(best, output_lod(gen, opts))
    seconds = time.perf_counter() - t0
    info.update({"method": "ga", "profile": profile, "seed": seed, "final_loss": float(loss),
                 "evaluations": int(len(trace)), "loss": "tree" if objective.tree else "silhouette",
                 "statistics": stats_source, "settings": asdict(settings), "options": asdict(opts),
                 "parts": sorted({gen.part_names[k] for k in np.unique(mesh.labels)}), **views.input_frame()})
    return write_result(out, mesh, info, trace, {
        "seconds": seconds, "statistics_seconds": t_stats, "search_seconds": objective.seconds,
        "seconds_per_evaluation": objective.seconds / max(objective.evaluations, 1)})
