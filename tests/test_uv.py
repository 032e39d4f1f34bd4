"""Texture coordinates: the layout measures on analytic cases, the dishes' charts on presets and
samples at every level of detail, and the glb's TEXCOORD_0."""
import numpy as np
import pytest

from ipm.generators import get_generator
from ipm.io.mesh import weld
from ipm.uv import area_quantile, corners_from_vertices, overlap, stretch, sweep_atlas

STRETCH_P95 = 4.0
"""A texel at most 4 times longer or shorter than its part's mean along any direction over 95 % of
the part's surface (a 1024-texel bitmap a part then keeps at least 256 texels across anywhere)."""


def test_overlap_counts_folded_and_stacked_triangles():
    square = np.array([[[0.1, 0.1], [0.9, 0.1], [0.9, 0.9]], [[0.1, 0.1], [0.9, 0.9], [0.1, 0.9]]])
    assert overlap(square, 64) == 0.0  # the shared diagonal counts for neither
    assert overlap(np.concatenate([square, square[:1]]), 64) == pytest.approx(0.5, abs=0.03)  # half covered twice
    folded = square.copy()
    folded[1, 1] = (0.9, 0.1)  # the second triangle folded over the first: a third of the union twice
    assert overlap(folded, 64) == pytest.approx(1 / 3, abs=0.03)


def test_stretch_is_one_for_a_similarity_and_the_anisotropy_otherwise():
    v = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [0.0, 0.5]])[f]
    s, area = stretch(v, f, uv)
    np.testing.assert_allclose(s, 1.0)
    np.testing.assert_allclose(area, 1.0)
    squeezed = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.5], [0.0, 0.5]])[f]  # x at half the density of y
    np.testing.assert_allclose(stretch(v, f, squeezed)[0], np.sqrt(2.0))
    assert np.isinf(stretch(v, f, np.zeros((2, 3, 2)) + [[[0, 0], [1, 1], [0.5, 0.5]]])[0]).all()


def test_area_quantile_weighs_by_area():
    assert area_quantile(np.array([1.0, 5.0]), np.array([9.0, 1.0]), 0.5) == 1.0
    assert area_quantile(np.array([1.0, 5.0]), np.array([1.0, 9.0]), 0.5) == 5.0


def test_corners_unwrap_a_seam_and_weld_splits_only_there():
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    uv = np.array([[0.9, 0.0], [0.0, 0.0], [0.9, 1.0], [0.0, 1.0]])  # u wraps between vertices 0 and 1
    corner = corners_from_vertices(faces, uv)
    assert corner[..., 0].max() == pytest.approx(1.0) and corner[..., 0].min() == pytest.approx(0.9)
    corner[1] = [[0.2, 0.0], [0.2, 1.0], [0.1, 1.0]]  # the second face on a chart of its own
    source, welded, wuv = weld(faces, corner)
    assert len(source) == 6 and sorted(source.tolist()) == [0, 1, 1, 2, 2, 3]
    np.testing.assert_allclose(wuv[welded], corner)
    same, faces_same, _ = weld(faces, np.zeros((2, 3, 2)))
    assert len(same) == 4 and np.array_equal(same[faces_same], faces)


def test_sweep_atlas_keeps_charts_apart_at_one_density():
    box, discs = sweep_atlas((3.0, 1.0), (0.3, 0.2))
    assert all(0 <= c - r and c + r <= 1 for cu, cv, r in discs for c in (cu, cv))
    assert (box[2] - box[0]) / (box[3] - box[1]) == pytest.approx(3.0)
    assert discs[0][2] / discs[1][2] == pytest.approx(1.5)
    assert discs[0][2] / (box[2] - box[0]) == pytest.approx(0.1)
    (du0, dv0, r0), (du1, dv1, r1) = discs
    assert np.hypot(du1 - du0, dv1 - dv0) > r0 + r1 and min(dv0 - r0, dv1 - r1) > box[3]


def _cases(name: str, n_samples: int):
    gen = get_generator(name)
    rng = np.random.default_rng(7)
    draw = (lambda: gen.sample(rng, handle=True)) if name == "dishes" else (lambda: gen.sample(rng))
    return gen, [*gen.presets.values(), *(draw() for _ in range(n_samples))]


@pytest.mark.parametrize("name, n_samples, raster_lods", [
    ("dishes", 3, (0,)), pytest.param("buildings", 4, (1, 2), marks=pytest.mark.slow),
    pytest.param("trees", 2, (0,), marks=pytest.mark.slow)])
def test_charts_do_not_overlap_and_stretch_is_bounded(name, n_samples, raster_lods):
    """Every part of every level on presets and samples: no texel in two triangles (rasterised at
    the levels named; the charts are drawn the same way at the others) and the stretch bound."""
    gen, xs = _cases(name, n_samples)
    for x in xs:
        for lod in gen.lods:
            m = gen.mesh(x, lod)
            assert m.uv.shape == (len(m.faces), 3, 2) and m.uv.min() > 0 and m.uv.max() < 1
            for k, part in enumerate(gen.part_names):
                sel = m.labels == k
                if not sel.any():
                    continue
                if lod in raster_lods:
                    assert overlap(m.uv[sel], 1024) == 0.0, (part, lod)
                s, area = stretch(m.vertices, m.faces[sel], m.uv[sel])
                assert np.isfinite(s).all(), (part, lod)
                assert area_quantile(s, area, 0.95) <= STRETCH_P95, (part, lod)


def test_dishes_uv_is_the_same_surface_point_at_every_level():
    """A profile point keeps its UV across levels of detail, so a texture serves every level."""
    gen = get_generator("dishes")
    x = gen.presets["mug"]
    coarse, fine = gen.mesh(x, 0), gen.mesh(x, 2)
    for m in (coarse, fine):  # the body's vertex at the outer wall's top, seen from u = 0
        body = m.labels == 0
        corners = m.vertices[m.faces[body]].reshape(-1, 3)
        uvs = m.uv[body].reshape(-1, 2)
        top = np.isclose(corners[:, 1], corners[:, 1].max()) & np.isclose(corners[:, 2], 0, atol=1e-6)
        outer = top & (corners[:, 0] >= corners[top, 0].max() - 1e-6)
        m.top_uv = np.unique(np.round(uvs[outer], 6), axis=0)
    np.testing.assert_allclose(coarse.top_uv, fine.top_uv)


def test_glb_carries_texcoords_split_only_at_seams(tmp_path):
    import trimesh

    from ipm.generators.dishes import _LOD
    from ipm.io.mesh import save_glb

    gen = get_generator("dishes")
    m = gen.mesh(gen.presets["mug"], 0)
    save_glb(tmp_path / "m.glb", m.vertices, m.faces, m.labels, m.part_names, m.uv, normals=m.normals)
    scene = trimesh.load(tmp_path / "m.glb")
    for k, name in enumerate(m.part_names):
        part = scene.geometry[name]
        sel = m.labels == k
        assert np.asarray(part.visual.uv).shape == (len(part.vertices), 2)
        # per corner, the file's UVs are the generator's (glTF's v runs down the image)
        got = np.asarray(part.visual.uv)[np.asarray(part.faces)]
        np.testing.assert_allclose(got, m.uv[sel], atol=1e-6)
        np.testing.assert_allclose(np.asarray(part.vertices)[np.asarray(part.faces)], m.vertices[m.faces[sel]],
                                   atol=1e-6)
        # split only where charts meet: the seam (a vertex a row) and the rings at the two caps' edges
        rows, ring = {"body": (2 * _LOD[0][0], _LOD[0][1]), "handle": _LOD[0][2:]}[name]
        assert len(part.vertices) == len(np.unique(m.faces[sel])) + rows + 2 * ring


@pytest.mark.parametrize("name", ["dishes", "buildings"])
def test_a_mesh_without_charts_is_the_same_mesh(name):
    """``uv=False`` (the learned samples' silhouettes) leaves only the texture coordinates out."""
    gen, xs = _cases(name, 1)
    for x in xs[-2:]:
        full, bare = gen.mesh(x, 1), gen.mesh(x, 1, uv=False)
        assert bare.uv is None and full.uv is not None
        for field in ("vertices", "faces", "normals", "labels"):
            assert np.array_equal(getattr(full, field), getattr(bare, field)), field
