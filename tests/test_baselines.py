"""What every baseline shares: the registry contract, the working volume, marching cubes, the
visual hull, the failure record and the ``ipm baseline`` command."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from baselines.common import extract_surface, input_views, write_failure
from ipm.hull import grid_points, object_box
from ipm.errors import UserError
from ipm.io import load_mesh
from ipm.methods import METHODS, row_label
from ipm.synth import LAYOUTS


@pytest.fixture(scope="module")
def hemi6(tmp_path_factory, mitsuba_cpu):
    """cup_1 with the input view and five hemisphere views at 96 px."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("baselines") / "cup_1"
    synthesize("cup_1", out, n_views=6, res=96, spp=4, progress=False)
    return out


@pytest.mark.parametrize("name", METHODS.names())
def test_registered_methods_declare_label_and_layout(name):
    fn = METHODS[name]
    assert fn.layout in LAYOUTS
    assert "{views}" in fn.label
    assert row_label(name, 1).endswith("1 view)") and row_label(name, 12).endswith("12 views)")


def test_object_box_contains_the_object_and_is_tight(hemi6):
    views = input_views(hemi6 / "transforms.json", None)
    lo, hi = object_box(views)
    v = np.asarray(load_mesh(hemi6 / "reference.ply").vertices)
    assert np.all(v.min(0) >= lo) and np.all(v.max(0) <= hi)
    # six views carve the frustum cube down to a box not much larger than the object
    assert np.prod(hi - lo) < 4.0 * np.prod(np.ptp(v, axis=0))


def test_extract_surface_of_an_analytic_sphere():
    lo, hi, n = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]), 48
    pts = grid_points(lo, hi, n)
    centre = np.array([0.1, -0.05, 0.2])
    field = (0.6 - np.linalg.norm(pts - centre, axis=1)).reshape(n, n, n)  # positive inside
    verts, faces = extract_surface(field, lo, hi, 0.0, inside_positive=True)
    r = np.linalg.norm(verts - centre, axis=1)
    assert abs(r.mean() - 0.6) < 0.01 and r.std() < 0.01
    mesh = trimesh.Trimesh(verts, faces)
    assert mesh.is_watertight and mesh.volume > 0  # closed and outward
    assert abs(mesh.volume - 4 / 3 * np.pi * 0.6**3) / (4 / 3 * np.pi * 0.6**3) < 0.03
    with pytest.raises(UserError, match="no surface"):
        extract_surface(np.ones((8, 8, 8)), lo, hi, 0.5, inside_positive=True)


@pytest.mark.slow
def test_visual_hull_contains_the_object_and_scores_between_the_reference_lines(hemi6, tmp_path):
    from ipm.metrics import evaluate_meshes
    from ipm.metrics.silhouette import raycasting_scene
    from ipm.metrics.volume import occupancy
    from ipm.reference_lines import bounding_sphere, convex_hull

    info = METHODS["visual_hull"](hemi6 / "transforms.json", tmp_path / "vh", profile="smoke", progress=False)
    assert info["views"] == 6 and (tmp_path / "vh" / "timing.json").is_file()
    hull = load_mesh(tmp_path / "vh" / "mesh.ply")
    assert hull.is_watertight
    reference = load_mesh(hemi6 / "reference.ply")
    # carving never removes the object: nearly every surface point of the reference is inside
    # (a margin of one 48^3 cell for the discretisation)
    pts = trimesh.sample.sample_surface(reference, 2000, seed=0)[0]
    cell = np.ptp(np.array(info["box"]), axis=0).max() / 48
    near = raycasting_scene(hull).compute_distance(pts.astype(np.float32)).numpy() < cell
    assert np.mean(occupancy(hull, pts) | near) > 0.98
    m = evaluate_meshes(reference, hull, n_views=16, res=64, grid=48)
    m_sphere = evaluate_meshes(reference, bounding_sphere(reference), n_views=16, res=64, grid=48)
    assert m_sphere["iou_mean"] < m["iou_mean"] <= 1.0
    m_convex = evaluate_meshes(reference, convex_hull(reference), n_views=16, res=64, grid=48)
    assert m_sphere["iou_mean"] < m_convex["iou_mean"] <= 1.0  # the convex hull is the tighter reference line


def test_baselines_refuse_too_few_views_and_unknown_profiles(hemi6, tmp_path):
    with pytest.raises(UserError, match="needs 2"):
        METHODS["visual_hull"](hemi6 / "transforms.json", tmp_path / "a", n_input_views=1, progress=False)
    with pytest.raises(UserError, match="unknown profile"):
        METHODS["visual_hull"](hemi6 / "transforms.json", tmp_path / "b", profile="turbo", progress=False)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_failure_record_flows_into_the_table(tmp_path):
    from ipm.table import build_table
    from ipm.workflow import evaluate_step

    from ipm.synth import write_reference

    ref_dir = tmp_path / "ref"
    write_reference("cup_1", ref_dir)
    write_failure(tmp_path / "rec", 0.0, {"method": "colmap_sfm"}, "registered 1 of 16 images")
    assert len(load_mesh(tmp_path / "rec" / "mesh.ply", allow_empty=True).faces) == 0
    out = tmp_path / "results" / "evaluate" / "colmap_sfm_16v" / "cup_1" / "s0"
    out.mkdir(parents=True)
    evaluate_step(str(ref_dir / "reference.ply"), str(ref_dir / "ground_truth.json"), str(tmp_path / "rec"),
                  str(out / "metrics.json"), str(out / "preview.png"),
                  {"label": "COLMAP SfM (16 views)", "kind": "baseline"}, seed=0, n_views=8, res=32, grid=16)
    assert json.loads((out / "metrics.json").read_text()) == {"failed": "registered 1 of 16 images"}
    assert (out / "preview.png").is_file()
    df = build_table([str(out / "metrics.json")], str(tmp_path / "t.csv"), str(tmp_path / "w.csv"))
    assert np.isnan(df["iou_mean"].iloc[0]) and df["note"].iloc[0] == "failed: registered 1 of 16 images"
    assert df["split"].iloc[0] == "dev" and df["seed"].iloc[0] == 0
    assert "COLMAP SfM (16 views)" in (tmp_path / "w.csv").read_text()


@pytest.mark.slow
def test_cli_baseline(hemi6, tmp_path):
    def ipm(*args):
        return subprocess.run([sys.executable, "-m", "ipm.cli", *args], capture_output=True, text=True, timeout=300)

    res = ipm("baseline", "visual_hull", "--views", str(hemi6 / "transforms.json"), "--out", str(tmp_path / "vh"),
              "--profile", "smoke", "--threads", "1", "--quiet")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "vh" / "mesh.ply").is_file()
    res = ipm("baseline", "nope", "--views", str(hemi6 / "transforms.json"), "--out", str(tmp_path / "x"))
    assert res.returncode == 2 and "unknown method 'nope'" in res.stderr and not (tmp_path / "x").exists()
    res = ipm("baseline", "diff", "--views", str(hemi6 / "transforms.json"), "--out", str(tmp_path / "x"))
    assert res.returncode == 2 and "not a baseline" in res.stderr
