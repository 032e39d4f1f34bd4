"""Analytic checks of the evaluation metrics (ipm.metrics)."""

import json
import math

import numpy as np
import pytest
import trimesh
from PIL import Image

from ipm.metrics import (
    chamfer, evaluate_meshes, fibonacci_cameras, occupancy, preview_png, raycast_masks,
    silhouette_iou, triangle_quality, volumetric_iou,
)


def sphere(x=0.0):
    return trimesh.creation.icosphere(subdivisions=4, radius=1.0).apply_translation([x, 0.0, 0.0])


def box(x=0.0):
    return trimesh.creation.box(extents=[1.0, 1.0, 1.0]).apply_translation([x, 0.0, 0.0])


def lens_iou(d, r=1.0):
    """IoU of two balls of radius r whose centres are d apart (lens volume formula)."""
    lens = math.pi * (4 * r + d) * (2 * r - d) ** 2 / 12
    return lens / (2 * 4 / 3 * math.pi * r**3 - lens)


@pytest.mark.slow
def test_mesh_against_itself_is_perfect():
    m = sphere()
    out = evaluate_meshes(m, m, n_views=16, res=64, grid=64)
    assert out["iou_mean"] == 1.0 and out["iou_min"] == 1.0 and out["iou_std"] == 0.0
    assert out["viou"] == 1.0
    assert out["chamfer_l2"] < 1e-4 and out["chamfer_l1"] < 1e-2
    assert out["recon_watertight"] and out["reference_watertight"]
    assert out["n_triangles"] == len(m.faces) and out["malformed_share"] == 0.0
    json.dumps(out)  # plain Python types only


@pytest.mark.parametrize("d", [0.5, 1.0, 1.5])
def test_two_spheres_volumetric_iou_matches_lens_formula(d):
    assert volumetric_iou(sphere(), sphere(d), grid=96)["viou"] == pytest.approx(lens_iou(d), abs=0.02)


def test_two_spheres_silhouette_iou_in_range_and_decreasing():
    ious = [silhouette_iou(sphere(), sphere(d), n_views=32, res=64)["iou_mean"] for d in (0.5, 1.0)]
    assert 0.0 < ious[1] < ious[0] < 1.0


@pytest.mark.parametrize("t", [0.1, 0.3])
def test_translated_box_volumetric_iou(t):
    assert volumetric_iou(box(), box(t), grid=64)["viou"] == pytest.approx((1 - t) / (1 + t), abs=0.02)


def test_translated_box_silhouette_iou_decreases():
    ious = [silhouette_iou(box(), box(t), n_views=32, res=64)["iou_mean"] for t in (0.0, 0.1, 0.3)]
    assert ious[0] == 1.0 and ious[0] > ious[1] > ious[2] > 0.0


def test_occupancy_of_intersecting_components_is_their_union():
    m = trimesh.util.concatenate([box(), box(0.5)])
    pts = np.array([[0.25, 0.01, 0.02], [-0.4, 0.0, 0.0], [0.9, 0.0, 0.0], [2.0, 0.0, 0.0], [0.25, 0.7, 0.0]])
    assert occupancy(m, pts).tolist() == [True, True, True, False, False]


def test_many_components_share_scenes_and_keep_their_union():
    """A tree-like mesh: 64 small disjoint cubes (one scene for all) inside two overlapping boxes."""
    from ipm.metrics.volume import disjoint_groups

    small = [trimesh.creation.box(extents=[0.1] * 3).apply_translation([x, y, 3.0])
             for x in np.linspace(-1.5, 1.5, 8) for y in np.linspace(-1.5, 1.5, 8)]
    m = trimesh.util.concatenate([box(), box(0.5), *small])
    parts = m.split(only_watertight=False)
    lo, hi = np.array([p.bounds[0] for p in parts]), np.array([p.bounds[1] for p in parts])
    groups = disjoint_groups(lo, hi)
    assert sorted(np.concatenate(groups).tolist()) == list(range(len(parts))) and len(groups) == 2
    for g in groups:  # no two boxes of a group overlap
        for i in g:
            for j in g:
                assert i == j or not np.all((lo[i] <= hi[j]) & (hi[i] >= lo[j]))
    pts = np.array([[0.25, 0.01, 0.02], [0.9, 0.0, 0.0], [1.5, 1.5, 3.0], [-1.5, 0.2143, 3.0],
                    [1.5, 1.5, 3.2], [0.0, 0.0, 3.0], [0.25, 0.7, 0.0]])
    assert occupancy(m, pts).tolist() == [True, True, True, True, False, False, False]


def test_grid_occupancy_equals_general_path_and_component_union():
    """Many small disjoint parts, a few intersecting ones and one sticking out of the grid: the grid
    fast path, the general path and an OR over one scene per part agree, on grid and random points."""
    from ipm.metrics.silhouette import open3d, raycasting_scene
    from ipm.metrics.volume import occupancy_grid, voxel_centres

    rng = np.random.default_rng(3)
    small = [(trimesh.creation.box(extents=[0.13] * 3) if (i + j) % 2 else
              trimesh.creation.icosphere(subdivisions=1, radius=0.08)).apply_translation([x, y, 1.1 + 0.3 * (i % 3)])
             for i, x in enumerate(np.linspace(-1.4, 1.4, 9)) for j, y in enumerate(np.linspace(-1.4, 1.4, 9))]
    big = [box(0.05), box(0.55), sphere(-0.6).apply_scale(0.45),
           trimesh.creation.icosphere(radius=0.3).apply_translation([1.6, 1.4, 1.5])]
    m = trimesh.util.concatenate(small + big)
    bounds = np.array([[-2.0] * 3, [2.0] * 3])  # centres on box()'s faces and on the parts' box planes
    pts = voxel_centres(bounds, 20)
    # on a face, parity is undefined and the grid's line rays and the points' own rays may differ;
    # everywhere else (the box planes included) the two paths agree
    on_face = raycasting_scene(m).compute_distance(open3d().core.Tensor(pts.astype(np.float32))).numpy() < 1e-6
    assert on_face.sum() > 20
    assert np.array_equal(occupancy_grid(m, bounds, 20)[~on_face], occupancy(m, pts)[~on_face])
    m.apply_translation(rng.uniform(-0.01, 0.01, 3))  # off the grid's planes, where parity is well defined
    parts = m.split(only_watertight=False)

    def union(pts):
        query = open3d().core.Tensor(pts.astype(np.float32))
        return np.any([raycasting_scene(p).compute_occupancy(query, nsamples=3).numpy() > 0.5 for p in parts], axis=0)

    for bounds, grid in ((m.bounds, 24), (m.bounds * [[0.7, 0.8, 0.9], [0.9, 0.6, 0.95]], 17)):
        pts = voxel_centres(bounds, grid)
        fast = occupancy_grid(m, bounds, grid)
        assert fast.any() and not fast.all()
        assert np.array_equal(fast, occupancy(m, pts)) and np.array_equal(fast, union(pts))
    pts = rng.uniform(m.bounds[0] - 0.2, m.bounds[1] + 0.2, size=(20000, 3))
    inside = occupancy(m, pts)
    assert inside.any() and np.array_equal(inside, union(pts))
    odd = np.array([[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0], [0.05, 0.0, 0.0]])  # non-finite points are outside
    assert occupancy(m, odd).tolist() == [False, False, True]
    assert not occupancy_grid(trimesh.Trimesh(), m.bounds, 4).any()


def test_disjoint_groups_is_the_greedy_partition():
    """Random boxes on an integer lattice (many touch): groups are pairwise disjoint and the
    same as a brute-force greedy colouring, largest box first."""
    from ipm.metrics.volume import disjoint_groups

    rng = np.random.default_rng(0)
    lo = rng.integers(0, 20, size=(300, 3)).astype(float)
    hi = lo + rng.integers(0, 4, size=(300, 3))
    overlap = np.all((lo[:, None] <= hi[None]) & (hi[:, None] >= lo[None]), axis=2)
    group_of = np.full(len(lo), -1)
    for i in np.argsort(-np.prod(hi - lo, axis=1), kind="stable"):
        group_of[i] = min(set(range(len(lo))) - set(group_of[overlap[i]].tolist()))
    expected = [np.flatnonzero(group_of == g) for g in range(group_of.max() + 1)]
    groups = disjoint_groups(lo, hi)
    assert len(groups) == len(expected) and all(np.array_equal(a, b) for a, b in zip(groups, expected))
    assert all(overlap[np.ix_(g, g)].sum() == len(g) for g in groups)


def test_fibonacci_cameras_look_at_centre_from_fixed_distance():
    centre, radius = np.array([1.0, 2.0, -3.0]), 0.7
    cams = fibonacci_cameras(centre, radius, n_views=64, fov_deg=40.0)
    assert len(cams) == 64
    dist = 1.25 * radius / math.sin(math.radians(20.0))
    pos = np.array([c[:3, 3] for c in cams])
    assert np.allclose(np.linalg.norm(pos - centre, axis=1), dist)
    to_centre = (centre - pos) / dist
    assert np.allclose([-c[:3, 2] for c in cams], to_centre)
    assert all(np.allclose(c[:3, :3].T @ c[:3, :3], np.eye(3)) and np.linalg.det(c[:3, :3]) > 0 for c in cams)
    assert all(c[1, 1] >= 0 for c in cams)  # image up never points down in the world
    assert abs(int((pos[:, 1] > centre[1]).sum()) - 32) <= 2


def test_raycast_mask_orientation():
    cam = np.eye(4)
    cam[2, 3] = 5.0  # at +z looking down -z, world +y up
    target = trimesh.creation.box(extents=[0.5, 0.5, 0.5]).apply_translation([1.0, 1.0, 0.0])
    mask = raycast_masks(target, [cam], res=64)[0]
    assert mask.sum() > 0 and mask[:32, 32:].sum() == mask.sum()  # top-right quadrant only


def test_triangle_quality_flags_sliver_and_degenerate():
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.8, 0], [0.5, 0.01, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0]], float)
    f = np.array([[0, 1, 2], [0, 1, 3], [4, 5, 6], [0, 2, 1]])  # good, sliver (~1.1 deg), zero area, good
    out = triangle_quality(trimesh.Trimesh(v, f, process=False), radius=1.0)
    assert out == {"n_triangles": 4, "malformed_share": 0.5}


def test_empty_reconstruction():
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    out = evaluate_meshes(sphere(), empty, n_views=8, res=32, grid=32)
    assert out["iou_per_view"] == [0.0] * 8
    assert out["iou_mean"] == 0.0 and out["viou"] == 0.0 and not out["recon_watertight"]
    assert out["chamfer_l2"] == float("inf") and out["chamfer_l1"] == float("inf")
    assert out["n_triangles"] == 0
    assert chamfer(sphere(), empty)["chamfer_l2"] == float("inf")


def test_invalid_reference_raises():
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(ValueError, match="empty"):
        evaluate_meshes(empty, sphere(), n_views=4, res=16, grid=16)
    bad = sphere()
    bad.vertices[0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        silhouette_iou(bad, sphere(), n_views=4, res=16)


def test_preview_png_written(tmp_path):
    path = tmp_path / "preview.png"
    preview_png(sphere(), sphere(0.5), str(path), n=4, res=32)
    img = np.asarray(Image.open(path))
    assert img.shape == (36, 4 * 36, 3)
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind
    colours = {tuple(c) for c in img.reshape(-1, 3)}
    assert {(255, 255, 255), (220, 40, 40), (40, 200, 220)} <= colours


def test_touching_closed_parts_stay_watertight():
    """Two closed boxes sharing a corner vertex position: watertight as given, not glued by welding."""
    a = trimesh.creation.box(extents=[1, 1, 1])
    b = trimesh.creation.box(extents=[1, 1, 1]).apply_translation([1, 1, 1])
    both = trimesh.util.concatenate([a, b])
    out = volumetric_iou(both, both, grid=32)
    assert out["reference_watertight"] and out["recon_watertight"] and out["viou"] == 1.0


def test_reference_masks_cast_once_give_the_same_metrics(tmp_path):
    """The workflow casts a case's reference masks once (``write_reference_masks``) for all its
    evaluations: read back they are the masks the metric casts, the metrics equal those cast in the
    evaluation itself, and a file cast for other views or from another reference is refused."""
    from ipm.errors import UserError
    from ipm.metrics.evaluate import evaluate_files
    from ipm.metrics.silhouette import bounding_sphere, read_reference_masks, write_reference_masks

    ref, rec = tmp_path / "ref.ply", tmp_path / "rec.ply"
    box().export(ref)
    sphere(0.3).export(rec)
    write_reference_masks(ref, tmp_path / "masks.npz", n_views=8, res=33)
    cached = read_reference_masks(tmp_path / "masks.npz", ref, 8, 33)
    reference = trimesh.load(ref)
    assert np.array_equal(cached, raycast_masks(reference, fibonacci_cameras(*bounding_sphere(reference), 8), 33))
    args = dict(n_views=8, res=33, grid=16)
    fresh = evaluate_files(ref, rec, tmp_path / "a.json", **args)
    reused = evaluate_files(ref, rec, tmp_path / "b.json", reference_masks=tmp_path / "masks.npz", **args)
    assert fresh == reused
    with pytest.raises(UserError, match="cast for 8 views at 33 px"):
        evaluate_files(ref, rec, tmp_path / "c.json", n_views=8, res=32, grid=16,
                       reference_masks=tmp_path / "masks.npz")
    box(0.1).export(tmp_path / "other.ply")
    with pytest.raises(UserError, match="another file"):
        read_reference_masks(tmp_path / "masks.npz", tmp_path / "other.ply", 8, 33)
    (tmp_path / "bad.npz").write_text("not an npz")
    with pytest.raises(UserError, match="not a reference-masks file"):
        read_reference_masks(tmp_path / "bad.npz", ref, 8, 33)
    assert not (tmp_path / "c.json").exists()
