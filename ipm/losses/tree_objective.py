"""The genetic path's objective: the loss of genomes against impostor targets, and the
canonical family the gene statistics are gathered on.

**Loss** (:class:`Objective`). Plants (``Generator.plant``: parts ``branch`` and ``foliage``): the
paper's ``1 - TSim * prod(multipliers)`` (``ipm.losses.tree``; 16 stripes over the object's
height, as on the authors' 256 px impostors with 16 px stripes) with the multipliers named in
``regularisers`` (default: leaf density, one of the paper's "average branches and leaves
density"; ``graph_vertices=N`` adds the paper's recommended branch-graph size regulariser with
target ``N``) and three of ours: the silhouette IoU in the input view (``placement``: TSim cannot
see the pose), the silhouette IoU of the candidate turned about its axis (``turns``: a round crown
rather than a fan seen edge-on) and a complexity budget (``max_graph_vertices``). Other generators
(the dishes ablation): ``1 - IoU`` of the silhouettes. The loss is the mean over the input views.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ipm.generators.base import Generator
from ipm.losses.impostors import Target, TurnedRays, bbox, cast_turned, make_target, mirror_about
from ipm.losses.tree import TreeStats, loss_terms
from ipm.methods.ga_genome import Genome
from ipm.methods.ga_options import GAOptions, uses_tree_loss
from ipm.render.cameras import orbit_camera


class Objective:
    """Loss of genomes against impostor targets (one per input view, or a statistics family).

    Plants: ``loss = 1 - TSim * prod(regularisers) * placement * symmetry * complexity``, all
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
        self._rays = TurnedRays(np.stack([t.rays for t in targets]), self.turns)
        self.evaluations = 0
        self.seconds = 0.0

    def render(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray, int | None]:
        """Impostor labels (n_targets, impostor, impostor) of genome ``g`` as placed, its
        silhouettes turned (n_targets, turns - 1, impostor, impostor) and its graph size."""
        x = self.genome.params(g)
        mesh, n_graph = self.genome.object_mesh(x, self.options.lod, uv=False)
        v = self.genome.place(g, mesh)[0]
        return *cast_turned(v, mesh, self._rays, self.genome.pose(g)[1]), n_graph

    def losses(self, g: np.ndarray) -> np.ndarray:
        """Loss against each target, shape (n_targets,), in [0, 1]."""
        t0 = time.perf_counter()
        images, turned, n_graph = self.render(g)
        out = np.array([self._loss(t, img, side, n_graph) for t, img, side in zip(self.targets, images, turned)])
        self.evaluations += 1
        self.seconds += time.perf_counter() - t0
        return out

    def __call__(self, g: np.ndarray) -> float:
        return float(np.mean(self.losses(g)))

    def _loss(self, target: Target, img: np.ndarray, turned: np.ndarray, n_graph: int | None) -> float:
        """Loss of one target from the candidate's labels as placed (H, W) and its silhouettes
        turned (turns - 1, H, W)."""
        box = bbox(img)
        if box is None:
            return 1.0
        ref = target.labels > 0
        if not self.tree:
            return 1.0 - _iou(ref, img > 0)
        sim = 1.0 - loss_terms(target.stats, TreeStats(img, graph_vertices=n_graph), self.regularisers,
                               stripe_height=None, n_stripes=self.options.n_stripes)["loss"]
        if self.options.placement == "box":
            sim *= box_iou(bbox(target.labels), box)
        elif self.options.placement == "mask":
            sim *= _iou(ref, img > 0)
        if self.turns > 1:
            side = np.mean([max(_iou(ref, im), _iou(target.mirror, im)) for im in turned])
            sim *= 1.0 - self.options.turn_weight * (1.0 - side)
        if self.options.max_graph_vertices is not None and n_graph is not None:
            sim *= min(1.0, self.options.max_graph_vertices / max(n_graph, 1))
        return float(1.0 - sim)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two boolean images (1 when both are empty)."""
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b)) / union if union else 1.0


def box_iou(a, b) -> float:
    """IoU of two pixel boxes (top, bottom, left, right)."""
    ih = max(0, min(a[1], b[1]) - max(a[0], b[0]))
    iw = max(0, min(a[3], b[3]) - max(a[2], b[2]))
    inter = ih * iw
    union = (a[1] - a[0]) * (a[3] - a[2]) + (b[1] - b[0]) * (b[3] - b[2]) - inter
    return inter / union if union > 0 else 0.0


CANONICAL_ELEVATION = 10.0
"""Elevation (degrees) of the statistics family's camera: near-horizontal, as tree photos are."""


def family_objective(generator: Generator, options: GAOptions) -> Objective:
    """An objective with one target per preset of ``generator``: the preset, 1 unit high, standing
    at the origin, seen from ``CANONICAL_ELEVATION`` with a known anchor (origin, height 1).
    Scored from the input view only (``turns = 1``): four presets seen from four sides cost four
    times as much, and the statistics only need to tell tree-like gene values from others."""
    from ipm.render.semantic import raycast_labels

    options = options.updated(turns=1)
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
