"""The texture stage: texels of a chart, the symmetry fill, painting a known albedo back under the
reference lighting, the scores, and textures through the glb and ``ipm generate``."""
import json

import numpy as np
import pytest

from ipm.errors import UserError
from ipm.texture import fill
from ipm.uv import texels

SQUARE = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]], [[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
PLANE = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0], [-1.0, 2.0, 0.0]])
PLANE_FACES = np.array([[0, 1, 2], [0, 2, 3]])


def test_texels_cover_the_chart_and_place_points_on_the_surface():
    tx = texels(PLANE, PLANE_FACES, SQUARE, 8)
    assert len(tx.rows) == 64  # every texel centre of the square, once
    assert len(set(zip(tx.rows.tolist(), tx.cols.tolist()))) == 64
    # row 0 is the image's top, v = 1: the plane's top edge (y = 2); column 0 is u = 0 (x = -1)
    top = tx.rows == 0
    np.testing.assert_allclose(tx.points[top, 1], 2 * (1 - 0.5 / 8))
    np.testing.assert_allclose(tx.points[tx.cols == 0, 0], -1 + 2 * 0.5 / 8)
    np.testing.assert_allclose(np.abs(tx.normals[:, 2]), 1.0)


def test_fill_takes_the_group_mean_then_the_part_mean():
    texture = np.zeros((2, 3, 3))
    texture[0, 0] = (1.0, 0.0, 0.0)
    texture[1, 0] = (0.0, 0.0, 1.0)
    seen = np.zeros((2, 3))
    seen[0, 0] = seen[1, 0] = 1.0
    rows, cols = np.nonzero(np.ones((2, 3)))
    groups = np.array([[0, 0, 0], [-1, -1, -1]])  # row 0 one group, row 1 none
    out = fill(texture, seen, (rows, cols), groups)
    np.testing.assert_allclose(out[0], [[1, 0, 0]] * 3)  # row 0 from its group
    np.testing.assert_allclose(out[1, 1:], [[0.5, 0, 0.5]] * 2)  # row 1 from the part's seen mean
    np.testing.assert_allclose(fill(texture, np.zeros((2, 3)), (rows, cols), groups), 0.5)  # nothing seen: grey


@pytest.fixture(scope="module")
def painted_plane(mitsuba_cpu):
    """A plane wearing a two-colour albedo, photographed under the reference lighting, painted back."""
    from ipm.generators.base import Mesh, vertex_normals
    from ipm.render.cameras import orbit_camera
    from ipm.render.textured import render_painted
    from ipm.texture import paint

    albedo = np.zeros((32, 32, 3))
    albedo[:16] = (0.7, 0.2, 0.1)
    albedo[16:] = (0.1, 0.5, 0.3)
    c2w = orbit_camera(np.array([0.0, 1.0, 0.0]), 4.0, 0.0, 20.0)[None]
    photo = render_painted(PLANE, PLANE_FACES, np.zeros(2, int), SQUARE, {0: albedo}, c2w, 0.9, 64, 64, 256)
    mask = render_painted(PLANE, PLANE_FACES, np.zeros(2, int), SQUARE, {0: np.ones((4, 4, 3))}, c2w, 0.9, 64, 64,
                          16).mean(-1) > 0.02

    class Flat:
        def texture_symmetry(self, part, res):
            return None

    mesh = Mesh(PLANE, PLANE_FACES, vertex_normals(PLANE, PLANE_FACES), SQUARE, np.zeros(2, int), ("body",))
    textures, seen = paint(Flat(), mesh, photo, mask.astype(np.float32), c2w, 0.9, "reference", 32, 64)
    return albedo, textures[0], seen[0], photo, mesh, mask, c2w


@pytest.mark.slow
def test_refinement_pulls_a_wrong_texture_to_the_photo(painted_plane):
    """From an albedo off by +0.15 everywhere, the refinement (a coarse stage, then texel-sized)
    fitted to the one photo brings the covered texels back: their error under a fifth of it,
    repeatably: a second run from the same seed gives the same texels to float32 rounding (the
    gradients' atomic adds in Dr.Jit's backward pass may land in another order: in one suite run
    6 of 3072 values differed in their last bit; another seed moves them by 0.025 on average)."""
    from ipm.texture import Refinement, refine

    albedo, _, _, photo, mesh, mask, c2w = painted_plane
    wrong = {0: np.clip(albedo + 0.15, 0.0, 1.0)}
    schedule = Refinement(stages=((8, 30), (32, 30)), lr=0.02, spp=16)
    fixed = refine(mesh, wrong, photo, mask.astype(np.float32), c2w, 0.9, schedule)
    inner = (slice(4, 12), slice(4, 28)), (slice(20, 28), slice(4, 28))
    before = np.mean([np.abs(wrong[0][r, c] - albedo[r, c]).mean() for r, c in inner])
    after = np.mean([np.abs(fixed[0][r, c] - albedo[r, c]).mean() for r, c in inner])
    assert after < before / 5  # measured 0.022 from 0.15
    again = refine(mesh, wrong, photo, mask.astype(np.float32), c2w, 0.9, schedule)
    np.testing.assert_allclose(fixed[0], again[0], rtol=0, atol=1e-6)
    other = refine(mesh, wrong, photo, mask.astype(np.float32), c2w, 0.9, schedule, seed=1)
    assert np.abs(other[0] - fixed[0]).max() > 1e-4  # the seed reaches the renders


def test_paint_recovers_the_albedo_under_the_reference_lighting(painted_plane):
    albedo, texture, seen, photo = painted_plane[:4]
    assert seen > 0.8
    inner = (slice(4, 12), slice(4, 28)), (slice(20, 28), slice(4, 28))
    for rows, cols in inner:  # away from the colour edge and the rim
        np.testing.assert_allclose(texture[rows, cols].reshape(-1, 3).mean(0), albedo[rows, cols][0, 0], atol=0.03)
    assert photo.max() > 0  # the photo itself is shaded: the albedo came back only through the division


def test_further_passes_take_the_painted_albedos_interreflections_into_the_shading(mitsuba_cpu):
    """A floor meeting a wall, grey albedo: a white mesh lights its own corner more than a grey one
    does, so one projection paints the corner too dark; a second pass, dividing by the shading the
    painted mesh itself gets, brings the albedo back."""
    from ipm.generators.base import Mesh, vertex_normals
    from ipm.render.cameras import orbit_camera
    from ipm.render.textured import render_painted
    from ipm.texture import paint

    v = np.array([[-1, 0, 0], [1, 0, 0], [1, 0, 2], [-1, 0, 2],  # floor, facing up
                  [-1, 0, 0], [1, 0, 0], [1, 2, 0], [-1, 2, 0]], float)  # wall, facing +z
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]])
    uv = np.array([[[0.0, 1.0], [0.5, 0.0], [0.5, 1.0]], [[0.0, 1.0], [0.0, 0.0], [0.5, 0.0]],
                   [[0.5, 0.0], [1.0, 0.0], [1.0, 1.0]], [[0.5, 0.0], [1.0, 1.0], [0.5, 1.0]]])
    labels = np.zeros(4, int)
    albedo = np.full((32, 32, 3), 0.4)
    c2w = orbit_camera(np.array([0.0, 0.6, 0.6]), 4.0, 0.0, 30.0)[None]
    photo = render_painted(v, f, labels, uv, {0: albedo}, c2w, 0.9, 64, 64, 256)
    mask = (render_painted(v, f, labels, uv, {0: np.ones((4, 4, 3))}, c2w, 0.9, 64, 64, 16).mean(-1) > 0.02)

    class Flat:
        def texture_symmetry(self, part, res):
            return None

    mesh = Mesh(v, f, vertex_normals(v, f), uv, labels, ("body",))
    bias = {}
    for passes in (1, 2):
        texture, _ = paint(Flat(), mesh, photo, mask.astype(np.float32), c2w, 0.9, "reference", 32, 64,
                           passes=passes)
        bias[passes] = texture[0].mean() - 0.4
    assert bias[1] < -0.03 and abs(bias[2]) < 0.01, bias
    with pytest.raises(UserError, match="at least one projection"):
        paint(Flat(), mesh, photo, mask.astype(np.float32), c2w, 0.9, "reference", 32, 64, passes=0)


def test_masked_scores_and_sides():
    from ipm.metrics.texture import masked_scores, sides

    rng = np.random.default_rng(0)
    ref = rng.random((32, 32, 3))
    mask = np.zeros((32, 32))
    mask[8:24, 8:24] = 1
    same = masked_scores(ref, ref, mask)
    assert same["psnr"] == float("inf") and same["ssim"] == pytest.approx(1.0)
    off = ref.copy()
    off[mask > 0] += 0.1
    off[mask == 0] = 0  # pixels outside the mask do not count
    assert masked_scores(off, ref, mask)["psnr"] == pytest.approx(20.0, abs=1e-6)
    with pytest.raises(UserError, match="empty"):
        masked_scores(ref, ref, np.zeros((32, 32)))
    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, :3, 3] = [[0, 0, 5], [4, 0, 3], [0, 0, -5]]
    assert sides(c2w, np.zeros(3), 1) == ["input", "seen", "unseen"]


def test_the_cameras_common_centre_is_the_point_they_orbit():
    """``look_at_centre`` of cameras looking at one point from the held layout finds that point."""
    from ipm.metrics.texture import look_at_centre
    from ipm.synth import view_cameras

    centre = np.array([0.3, -0.2, 1.1])
    c2w = view_cameras(centre, 0.8, 16, 30.0, 20.0, layout="held")
    np.testing.assert_allclose(look_at_centre(c2w), centre, atol=1e-6)


def test_textures_go_through_the_glb_and_generate(tmp_path, mitsuba_cpu):
    from ipm.generate import generate
    from ipm.generators import get_generator
    from ipm.io.views import linear_from_srgb
    from ipm.io.mesh import read_textured_glb
    from ipm.methods.results import write_result

    gen = get_generator("dishes")
    mesh = gen.mesh(gen.presets["mug"], 0)
    rng = np.random.default_rng(1)
    textures = {0: rng.random((16, 16, 3)), 1: rng.random((16, 16, 3))}
    write_result(tmp_path / "r", mesh, {"generator": "dishes", "params": gen.spec.as_dict(gen.presets["mug"])},
                 {"seconds": 1.0}, textures=textures)
    assert sorted(p.name for p in (tmp_path / "r" / "textures").iterdir()) == ["body.png", "handle.png"]
    v, f, labels, uv, back = read_textured_glb(tmp_path / "r" / "mesh.glb")
    for k in (0, 1):  # 8-bit sRGB: within a step of the linear values
        np.testing.assert_allclose(back[k], linear_from_srgb(np.round(_srgb(textures[k]) * 255) / 255), atol=1e-6)
    np.testing.assert_allclose(uv, mesh.uv, atol=1e-6)
    (tmp_path / "p.json").write_text(json.dumps({"params": gen.spec.as_dict(gen.presets["mug"])}))
    generate("dishes", tmp_path / "p.json", 2, tmp_path / "g.glb", textures=tmp_path / "r" / "textures")
    fine = gen.mesh(gen.presets["mug"], 2)
    _, _, _, uv2, back2 = read_textured_glb(tmp_path / "g.glb")
    np.testing.assert_allclose(uv2, fine.uv, atol=1e-6)  # level 2 on the same charts
    np.testing.assert_allclose(back2[0], back[0])
    with pytest.raises(UserError, match="not found"):
        generate("dishes", tmp_path / "p.json", 1, tmp_path / "h.glb", textures=tmp_path / "none")
    with pytest.raises(UserError, match="glb"):
        generate("dishes", tmp_path / "p.json", 1, tmp_path / "h.ply", textures=tmp_path / "r" / "textures")


def _srgb(x):
    x = np.clip(x, 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def test_dishes_group_texels_by_their_height_round_the_axis():
    """Texels of one group lie at one height of the body (a row of the unrolled strip) or one
    distance from a bottom's centre: a mug's body drawn at level 1 shows it."""
    from ipm.generators import get_generator

    gen = get_generator("dishes")
    mesh = gen.mesh(gen.presets["mug"], 1)
    groups = gen.texture_symmetry(0, 128)
    sel = mesh.labels == 0
    tx = texels(mesh.vertices, mesh.faces[sel], mesh.uv[sel], 128)
    g = groups[tx.rows, tx.cols]
    assert (g >= 0).mean() > 0.95  # the charts' texels are grouped (a few at a disc's rim are not)
    radius = np.hypot(tx.points[:, 0], tx.points[:, 2])
    for k in np.unique(g[g >= 0])[::7]:
        same = g == k
        if same.sum() > 20:  # a row round the axis: one height, or one radius on a bottom
            assert min(np.ptp(tx.points[same, 1]), np.ptp(radius[same])) < 0.03
    assert gen.texture_symmetry(1, 64).max() >= 0 and get_generator("buildings").texture_symmetry(0, 64) is None


def test_pad_gives_the_gutter_its_nearest_chart_colour():
    from ipm.uv import pad

    texture = np.zeros((4, 6, 3))
    texture[1:3, 1:3] = (1.0, 0.5, 0.0)
    texture[1:3, 4] = (0.0, 0.0, 1.0)
    rows, cols = np.nonzero(texture.sum(-1) > 0)
    out = pad(texture, (rows, cols))
    np.testing.assert_allclose(out[0, 0], (1.0, 0.5, 0.0))  # beside the first chart
    np.testing.assert_allclose(out[3, 5], (0.0, 0.0, 1.0))  # beside the second
    np.testing.assert_allclose(out[rows, cols], texture[rows, cols])  # the charts untouched
