"""Shape IoU: silhouette IoU after the best yaw + translation + scale alignment."""
import math

import numpy as np
import trimesh

from ipm.metrics.align import align_similarity, base_centre, shape_iou, similarity_matrix
from ipm.metrics.silhouette import bounding_sphere, silhouette_iou

FAST = dict(n_views=16, res=96, search_views=12, search_res=48, max_evals=80)


def asymmetric():
    """A box with a sphere stuck on one side: no yaw symmetry, standing on y = 0."""
    box = trimesh.creation.box(extents=[1.0, 1.0, 0.6]).apply_translation([0.0, 0.5, 0.0])
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.3).apply_translation([0.6, 0.8, 0.2])
    return trimesh.util.concatenate([box, ball])


def test_known_similarity_is_undone():
    ref = asymmetric()
    radius = bounding_sphere(ref)[1]
    applied = similarity_matrix(math.radians(40.0), np.array([0.3, 0.1, -0.25]) * radius, 1.2, base_centre(ref))
    moved = ref.copy().apply_transform(applied)
    out = shape_iou(ref, moved, **FAST)
    assert out["world_iou"] < 0.6
    assert out["shape_iou"] > 0.97
    assert abs(out["align_yaw_deg"] + 40.0) < 2.0
    assert abs(out["align_scale"] - 1 / 1.2) < 0.02
    found = similarity_matrix(math.radians(out["align_yaw_deg"]), out["align_translation"], out["align_scale"],
                              out["align_pivot"])
    assert np.allclose(found @ applied, np.eye(4), atol=0.03)  # the recovered transform inverts the applied one


def test_a_result_placed_far_off_is_still_aligned():
    """A reconstruction of the right shape put ten radii away and three times too large (as a
    photo's wrong camera places one) aligns onto the reference: the search reaches the box match."""
    ref = asymmetric()
    radius = bounding_sphere(ref)[1]
    applied = similarity_matrix(math.radians(25.0), np.array([8.0, 0.0, -6.0]) * radius, 3.0, base_centre(ref))
    out = shape_iou(ref, ref.copy().apply_transform(applied), **FAST)
    assert out["world_iou"] < 0.05
    assert out["shape_iou"] > 0.95
    assert abs(out["align_scale"] - 1 / 3.0) < 0.02


def test_identical_mesh_keeps_identity():
    ref = asymmetric()
    out = shape_iou(ref, ref.copy(), **FAST)
    assert out["shape_iou"] == out["world_iou"] == 1.0
    assert out["align_yaw_deg"] == 0.0 and out["align_shift"] == 0.0 and out["align_scale"] == 1.0


def test_world_iou_is_the_metric_and_alignment_never_hurts():
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.45).apply_translation([0.2, 0.0, 0.1])
    out = shape_iou(box, sphere, **FAST)
    assert out["world_iou"] == silhouette_iou(box, sphere, n_views=16, res=96)["iou_mean"]
    assert out["shape_iou"] >= out["world_iou"]
    assert out["shape_iou"] > out["world_iou"] + 0.05  # centring and growing the sphere helps


def test_empty_and_non_finite_reconstructions():
    ref = asymmetric()
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    out = shape_iou(ref, empty, **FAST)
    assert out["shape_iou"] == 0.0 and out["align_scale"] == 1.0 and out["align_shift"] == 0.0
    bad = ref.copy()
    bad.vertices[:] = np.nan
    assert shape_iou(ref, bad, **FAST)["shape_iou"] == 0.0
    assert align_similarity(ref, empty, n_views=4, res=16)["scale"] == 1.0
