"""The report's gallery sheet: three novel views framed by the reference, shaded and as the
wireframe of the visible edges; a clear placeholder where there is no mesh."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

from ipm.io import save_ply
from ipm.render.cameras import orbit_camera, project
from ipm.render.gallery import FOV_DEG, MARGIN, VIEWS, gallery_cameras, gallery_sheet, wireframe

RES = 48


@pytest.fixture
def meshes(tmp_path):
    """A reference box and a sphere reconstruction inside it, as PLY files."""
    box = trimesh.creation.box(extents=(1.0, 1.4, 1.0))
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.55)
    paths = {"box": tmp_path / "reference.ply", "sphere": tmp_path / "mesh.ply"}
    save_ply(paths["box"], box.vertices, box.faces)
    save_ply(paths["sphere"], sphere.vertices, sphere.faces, labels=np.zeros(len(sphere.faces), int))
    return paths


def test_sheet_has_shaded_and_wireframe_rows_of_three_views(meshes, tmp_path, mitsuba_cpu):
    out = tmp_path / "gallery.png"
    gallery_sheet(str(meshes["sphere"]), str(meshes["box"]), str(out), res=RES, spp=4)
    img = np.asarray(Image.open(out).convert("RGB"), float)
    assert img.shape == (2 * RES, len(VIEWS) * RES, 3)
    for k in range(len(VIEWS)):
        shaded = img[:RES, k * RES:(k + 1) * RES].mean(-1)
        lines = img[RES:, k * RES:(k + 1) * RES].mean(-1)
        seen = lines < 250  # the silhouette's fill and the edges over it
        assert 0.1 < seen.mean() < 0.5 and lines[:4, :4].min() > 250  # the sphere, on white paper
        assert (lines[seen] < 150).mean() > 0.1  # edges drawn over the fill
        assert np.abs(shaded[seen] - shaded[0, 0]).mean() > 10  # shaded where the sphere is
        assert np.abs(shaded[~seen] - shaded[0, 0]).max() < 3  # plain background elsewhere


@pytest.mark.parametrize("kind", ["missing", "empty"])
def test_no_mesh_gives_a_placeholder_of_the_same_size(meshes, tmp_path, kind, mitsuba_cpu):
    mesh = tmp_path / "none.ply"
    if kind == "empty":
        save_ply(mesh, np.zeros((0, 3)), np.zeros((0, 3), int))
    out = tmp_path / "gallery.png"
    gallery_sheet(str(mesh), str(meshes["box"]), str(out), res=RES, spp=4)
    img = np.asarray(Image.open(out).convert("L"), float)
    assert img.shape == (2 * RES, len(VIEWS) * RES)
    assert img[:8, :8].max() < 80 and img.max() > 150  # dark, with light text on it


def test_cameras_frame_the_reference_whole_and_tight():
    box = trimesh.creation.box(extents=(2.0, 0.5, 1.0))
    for c2w in gallery_cameras(box):
        px = project(box.vertices, c2w, np.radians(FOV_DEG), RES, RES)
        reach = np.abs(px - RES / 2).max() / (RES / 2)  # farthest corner from the centre, 1 = the border
        assert 0.85 < reach <= 1.0 / MARGIN + 1e-9


def test_wireframe_draws_only_the_visible_edges():
    """A small box hidden behind a big one adds no line; beside it, it does."""
    front = trimesh.creation.box(extents=(1.0, 1.0, 0.2))
    hidden = trimesh.creation.box(extents=(0.3, 0.3, 0.3), transform=trimesh.transformations.translation_matrix(
        (0.1, 0.1, -1.0)))
    beside = trimesh.creation.box(extents=(0.3, 0.3, 0.3), transform=trimesh.transformations.translation_matrix(
        (0.9, 0.0, -1.0)))
    cams = orbit_camera(np.zeros(3), 4.0, 0.0, 0.0)[None]  # looking down -z at the front box
    alone = wireframe(front, cams, 96)
    assert np.allclose(wireframe(trimesh.util.concatenate([front, hidden]), cams, 96), alone, atol=1e-6)
    assert not np.allclose(wireframe(trimesh.util.concatenate([front, beside]), cams, 96), alone, atol=1e-3)


def test_a_textured_result_wears_its_textures(tmp_path, mitsuba_cpu):
    """A result folder with a textured mesh.glb (a red body, a blue handle) is drawn in them, not
    in the part colours (a grey body)."""
    from ipm.generators import get_generator
    from ipm.methods.results import write_result

    gen = get_generator("dishes")
    mesh = gen.mesh(gen.presets["mug"], 0)
    red, blue = np.tile([0.8, 0.05, 0.05], (8, 8, 1)), np.tile([0.05, 0.05, 0.8], (8, 8, 1))
    write_result(tmp_path / "r", mesh, {"generator": "dishes"}, {"seconds": 1.0}, textures={0: red, 1: blue})
    out = tmp_path / "gallery.png"
    gallery_sheet(str(tmp_path / "r" / "mesh.ply"), str(tmp_path / "r" / "mesh.ply"), str(out), res=RES, spp=4)
    img = np.asarray(Image.open(out).convert("RGB"), float)[:RES]
    cup = np.abs(img - img[0, 0]).sum(-1) > 30  # not the plain background
    r, g, b = (img[..., c][cup].mean() for c in range(3))
    assert cup.mean() > 0.1 and r > 2 * g and r > b
