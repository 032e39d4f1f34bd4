"""COLMAP baselines, stage by stage: frame conventions, similarity alignment, Poisson meshing,
a known-pose run on a small textured ring, the failure path and bad input."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import trimesh

from baselines.colmap.geometry import apply_similarity, camera_centre, robust_umeyama, umeyama
from ipm.errors import UserError
from ipm.render.cameras import colmap_to_gl, gl_to_colmap, look_at, project


def _random_cameras(rng, n=8):
    eyes = rng.normal(size=(n, 3))
    eyes = 3.0 * eyes / np.linalg.norm(eyes, axis=1, keepdims=True)
    return [look_at(e, rng.normal(scale=0.2, size=3)) for e in eyes]


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_pose_round_trip_and_projection(rng):
    """OpenGL c2w -> COLMAP cam_from_world -> back is the identity, the pose is rigid, the
    centre is the eye, and COLMAP's pinhole projection equals ipm's."""
    import pycolmap

    w, h, fov = 320, 240, 0.8
    f = 0.5 * w / np.tan(0.5 * fov)
    cam = pycolmap.Camera(model="PINHOLE", width=w, height=h, params=[f, f, w / 2, h / 2])
    pts = rng.normal(scale=0.3, size=(50, 3))
    for c2w in _random_cameras(rng):
        m = gl_to_colmap(c2w)
        assert m.shape == (3, 4)
        np.testing.assert_allclose(m[:, :3] @ m[:, :3].T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m[:, :3]) == pytest.approx(1.0)
        np.testing.assert_allclose(colmap_to_gl(m), c2w, atol=1e-12)
        np.testing.assert_allclose(camera_centre(m), c2w[:3, 3], atol=1e-12)
        pose = pycolmap.Rigid3d(m)  # the matrix survives pycolmap's quaternion storage
        np.testing.assert_allclose(pose.matrix(), m, atol=1e-12)
        cam_pts = pts @ m[:, :3].T + m[:, 3]
        assert np.all(cam_pts[:, 2] > 0), "COLMAP cameras look down +z at the scene"
        np.testing.assert_allclose(cam.img_from_cam(cam_pts), project(pts, c2w, fov, w, h), atol=1e-9)


def test_umeyama_recovers_a_similarity(rng):
    src = rng.normal(size=(20, 3))
    s, r, t = 2.7, _random_rotation(rng), rng.normal(size=3)
    dst = apply_similarity(src, s, r, t)
    s2, r2, t2 = umeyama(src, dst)
    assert s2 == pytest.approx(s, rel=1e-10)
    np.testing.assert_allclose(r2, r, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-10)
    # a mirrored target is no rotation: the best proper rotation is returned
    _, r3, _ = umeyama(src, dst * np.array([1, 1, -1]))
    assert np.linalg.det(r3) == pytest.approx(1.0)


def test_robust_umeyama_drops_misregistered_cameras(rng):
    angles = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = np.stack([np.cos(angles), 0.3 * np.ones(16), np.sin(angles)], 1) * 3.0
    s, r, t = 0.4, _random_rotation(rng), rng.normal(size=3)
    model = (ring - t) @ r / s  # model frame: ring = s R model + t
    model += rng.normal(scale=1e-4, size=model.shape)
    model[3] += 2.0  # two cameras registered in the wrong place
    model[11] -= 1.5
    s2, r2, t2, inl = robust_umeyama(model, ring)
    assert inl.sum() == 14 and not inl[3] and not inl[11]
    assert s2 == pytest.approx(s, rel=1e-3)
    np.testing.assert_allclose(r2, r, atol=1e-3)
    np.testing.assert_allclose(apply_similarity(model[inl], s2, r2, t2), ring[inl], atol=2e-3)


def test_poisson_of_oriented_sphere_points(rng):
    """Points on a sphere with observer directions outward give a sphere of the right radius,
    trimmed and cropped as asked; a handful of points is a MeshingError."""
    from baselines.colmap.meshing import MeshingError, oriented_normals, poisson_mesh

    p = rng.normal(size=(3000, 3))
    p = 0.5 * p / np.linalg.norm(p, axis=1, keepdims=True) + np.array([1.0, 2.0, 3.0])
    dirs = p - np.array([1.0, 2.0, 3.0])
    n = oriented_normals(p, dirs)
    assert np.all((n * dirs).sum(1) > 0)
    v, f = poisson_mesh(p, n, depth=6, trim=0.05, box=(np.array([0, 0, 0]), np.array([5, 2.2, 5])))
    r = np.linalg.norm(v - np.array([1.0, 2.0, 3.0]), axis=1)
    assert np.all(np.abs(r - 0.5) < 0.03)
    assert v[:, 1].max() <= 2.2 + 1e-9  # cropped to the box
    with pytest.raises(MeshingError):
        poisson_mesh(p[:5], n[:5])


@pytest.fixture(scope="module")
def ring16(tmp_path_factory):
    """cup_1 rendered with texture on a 16-view ring (22.5 degree steps) at 384 px; SIFT needs
    the samples (at 8 spp the render noise costs half the matches)."""
    from ipm.runtime import set_mitsuba_variant
    from ipm.synth import synthesize

    set_mitsuba_variant("cpu", 1)
    out = tmp_path_factory.mktemp("colmap") / "cup_1_ring16"
    synthesize("cup_1", out, n_views=16, res=384, spp=32, progress=False, layout="ring")
    return out


def _subset(src, dst, idx):
    """A transforms.json in ``dst`` with frames ``idx`` of ``src`` (images linked, not copied)."""
    data = json.loads((src / "transforms.json").read_text())
    data["frames"] = [data["frames"][i] for i in idx]
    dst.mkdir()
    for sub in ("rgb", "masks"):
        os.symlink(src / sub, dst / sub)
    (dst / "transforms.json").write_text(json.dumps(data))
    return dst / "transforms.json"


def _silhouette_iou(reference, mesh):
    from ipm.metrics import silhouette_iou

    return silhouette_iou(reference, mesh, n_views=16, res=128)["iou_mean"]


@pytest.mark.slow
def test_known_pose_run_meshes_the_cup(ring16, tmp_path):
    from ipm.io import load_mesh
    from ipm.methods import METHODS
    from ipm.reference_lines import bounding_sphere

    out = tmp_path / "known"
    info = METHODS["colmap_known"](ring16 / "transforms.json", out, progress=False)
    assert "failed" not in info
    assert info["registered"].startswith("16 of 16")
    assert info["points_in_box"] >= 500
    assert info["dense"].startswith("not available")
    saved = json.loads((out / "info.json").read_text())
    assert saved["points"] == info["points"] and saved["seconds"] > 0
    assert json.loads((out / "timing.json").read_text())["seconds"] > 0
    ref, mesh = load_mesh(ring16 / "reference.ply"), load_mesh(out / "mesh.ply")
    assert len(mesh.faces) > 1000
    # in the world frame: the mesh's box is close to the reference's
    np.testing.assert_allclose(mesh.bounds, ref.bounds, atol=0.15 * np.ptp(ref.bounds, axis=0).max())
    iou = _silhouette_iou(ref, mesh)
    sphere = _silhouette_iou(ref, bounding_sphere(ref))
    assert iou > 0.8 and iou > sphere + 0.25, (iou, sphere)


@pytest.mark.slow
def test_sfm_run_is_aligned_to_the_world(ring16, tmp_path):
    """Pose-free SfM registers most views, its camera centres land on the known ones after the
    similarity, and the mesh sits on the reference in the world frame."""
    from ipm.io import load_mesh
    from ipm.methods import METHODS
    from ipm.reference_lines import bounding_sphere

    out = tmp_path / "sfm"
    info = METHODS["colmap_sfm"](ring16 / "transforms.json", out, progress=False)
    assert "failed" not in info
    assert info["n_registered"] >= 8 and info["registered"] == f"{info['n_registered']} of 16 images"
    assert info["alignment"]["inliers"] >= 8
    assert info["alignment"]["rms_relative_to_ring"] < 0.01
    ref, mesh = load_mesh(ring16 / "reference.ply"), load_mesh(out / "mesh.ply")
    np.testing.assert_allclose(mesh.bounds, ref.bounds, atol=0.2 * np.ptp(ref.bounds, axis=0).max())
    iou = _silhouette_iou(ref, mesh)
    assert iou > _silhouette_iou(ref, bounding_sphere(ref)) + 0.1, iou


@pytest.mark.slow
def test_unregistrable_views_fail_without_raising(ring16, tmp_path):
    """Two opposite views share no feature: SfM registers nothing and known-pose
    triangulation finds no point; both write an empty mesh and ``failed``."""
    from ipm.methods import METHODS

    views = _subset(ring16, tmp_path / "opposite", [0, 8])
    for name in ("colmap_sfm", "colmap_known"):
        out = tmp_path / name
        info = METHODS[name](views, out, profile="smoke", progress=False)
        assert info["failed"], name
        saved = json.loads((out / "info.json").read_text())
        assert saved["failed"] == info["failed"]
        assert json.loads((out / "timing.json").read_text())["failed"] == info["failed"]
        header = (out / "mesh.ply").read_bytes().split(b"end_header")[0]
        assert b"element vertex 0" in header and b"element face 0" in header
    assert "registered 0 of 2" in json.loads((tmp_path / "colmap_sfm" / "info.json").read_text())["failed"]
    assert "sparse points" in json.loads((tmp_path / "colmap_known" / "info.json").read_text())["failed"]


@pytest.mark.slow
def test_bad_input_raises_user_error(ring16, tmp_path):
    from ipm.methods import METHODS

    with pytest.raises(UserError, match="profile"):
        METHODS["colmap_known"](ring16 / "transforms.json", tmp_path / "a", profile="fast", progress=False)
    views = _subset(ring16, tmp_path / "missing", [0, 1, 2])
    data = json.loads(views.read_text())
    data["frames"][1]["file_path"] = "rgb/nope.png"
    views.write_text(json.dumps(data))
    with pytest.raises(UserError, match="nope.png"):
        METHODS["colmap_sfm"](views, tmp_path / "b", progress=False)
    assert not (tmp_path / "b").exists()
    with pytest.raises(UserError):
        METHODS["colmap_known"](ring16 / "transforms.json", tmp_path / "c", n_input_views=1, progress=False)
    from PIL import Image

    small = _subset(ring16, tmp_path / "small", [0, 1])
    data = json.loads(small.read_text())
    Image.new("RGB", (32, 32)).save(tmp_path / "small" / "tiny.png")
    data["frames"][0]["file_path"] = "tiny.png"
    small.write_text(json.dumps(data))
    with pytest.raises(UserError, match="32x32"):
        METHODS["colmap_known"](small, tmp_path / "d", progress=False)
