"""The references' materials: the bake through a part's UVs, a cup's print and a building's
roof and walls, each seeded."""
import numpy as np

from ipm.render.appearance import bake, building_materials, cup_design, cup_material, reference_textures

SQUARE_UV = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]], [[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
SQUARE_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


def test_bake_puts_each_texel_at_its_surface_point_with_gltf_rows():
    """A unit square whose UVs are its x and y: texel (row, col) holds the point (u, v, 0) of its
    centre, the first row at v = 1; UVs one to the right (past 1) wrap to the same bitmap."""
    size = 16
    tex = bake(SQUARE_V, SQUARE_F, SQUARE_UV, lambda p, n: p, size)
    centres = (np.arange(size) + 0.5) / size
    np.testing.assert_allclose(tex[:, :, 0], np.tile(centres, (size, 1)), atol=1e-9)
    np.testing.assert_allclose(tex[:, :, 1], np.tile(centres[::-1, None], (1, size)), atol=1e-9)
    shifted = SQUARE_UV + np.array([0.5, 0.0])  # u in [0.5, 1.5]: the part past 1 wraps to [0, 0.5]
    wrapped = bake(SQUARE_V, SQUARE_F, shifted, lambda p, n: p, size)
    np.testing.assert_allclose(wrapped[:, size // 2:, 0], tex[:, : size // 2, 0], atol=1e-9)
    np.testing.assert_allclose(wrapped[:, : size // 2, 0], tex[:, size // 2:, 0], atol=1e-9)


def test_bake_fills_uncovered_texels_from_their_nearest_covered_one():
    """One triangle covers the half u >= v of the square: every other texel takes a covered
    texel's colour from across the diagonal (its x between the texel's own u and v), so bilinear
    filtering at a chart's border mixes in no background."""
    size = 16
    tex = bake(SQUARE_V, SQUARE_F[:1], SQUARE_UV[:1], lambda p, n: np.column_stack([p[:, 0], 1 + 0 * p[:, :2]]),
               size)
    assert np.all(tex[:, :, 1] == 1.0)  # no texel kept the background
    centres = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(centres, centres[::-1])  # glTF rows: the first at v = 1
    np.testing.assert_allclose(tex[:, :, 0][u > v], u[u > v], atol=1e-9)
    x, lo, hi = tex[:, :, 0][u < v], u[u < v], v[u < v]
    assert np.all((x >= lo - 1e-9) & (x <= hi + 1e-9)) and np.mean(x > lo + 1e-9) > 0.5


def _ring(radius, height, n=720):
    """Points round a cylinder's outside at ``height`` (its axis the y axis) and their normals."""
    a = np.linspace(-np.pi, np.pi, n, endpoint=False)
    p = np.stack([radius * np.cos(a), np.full(n, height), radius * np.sin(a)], 1)
    return a, p, np.stack([np.cos(a), np.zeros(n), np.sin(a)], 1)


def _parallel(colours, ref):
    """Which colours are a positive multiple of ``ref`` (the iron spots only darken a colour)."""
    unit = colours / np.linalg.norm(colours, axis=1, keepdims=True)
    return unit @ (ref / np.linalg.norm(ref)) > 1 - 1e-9


def test_a_cup_wears_bands_all_round_and_a_star_on_one_side():
    """On a cylinder's outside the design's band colour goes all round at the bands' height, and
    at the star's height only near the star's azimuth; inside, the print is absent."""
    seed = 5
    design = cup_design(seed)
    body = np.array([[0.3, 0.0, 0.0], [-0.3, 1.0, 0.0], [0.0, 0.5, 0.3], [0.0, 0.5, -0.3]])
    colour = cup_material(body, seed)
    a, p, n = _ring(0.3, design["top"] - 0.5 * design["widths"][0])
    band = _parallel(colour(p, n), design["band"])
    assert band.mean() > 0.85
    assert not _parallel(colour(p * [0.9, 1, 0.9], -n), design["band"]).any()  # the inside
    a, p, n = _ring(0.3, design["star_h"])
    star = _parallel(colour(p, n), design["band"])
    off = np.abs((a - design["star_at"] + np.pi) % (2 * np.pi) - np.pi)
    assert star[off < 0.05].all() and not star[off > 1.5].any()
    assert np.array_equal(colour(p, n), cup_material(body, seed)(p, n))


def test_a_pitched_roof_is_tiled_in_courses_a_flat_one_gravel_and_a_parapet_masonry():
    """Down a 35-degree roof the shadowed lower edge of each 0.3 m course (0.03 units) comes back
    at the course's period; a level roof is grey gravel; a roof part's upright face is the walls'."""
    m = building_materials(np.zeros((1, 3)), seed=3)
    slope = np.radians(35.0)
    n = np.tile([0.0, np.cos(slope), np.sin(slope)], (3000, 1))
    y = np.linspace(0.0, 0.3, 3000, endpoint=False)  # ten courses
    p = np.stack([np.full_like(y, 0.00625), y, -y / np.tan(slope)], 1)  # mid-tile in either course
    lum = m["roof"](p, n).sum(1)
    shadow = lum < 0.6 * np.median(lum)
    assert abs(shadow.mean() - 0.15) < 0.03
    starts = np.flatnonzero(shadow[1:] & ~shadow[:-1])
    assert len(starts) == 9 or len(starts) == 10
    np.testing.assert_allclose(np.diff(y[starts + 1]), 0.03, atol=2e-4)
    level = np.tile([0.0, 1.0, 0.0], (50, 1))
    gravel = m["roof"](np.random.default_rng(0).random((50, 3)), level)
    chroma = gravel / gravel.sum(1, keepdims=True)
    assert np.ptp(chroma, axis=0).max() < 1e-9 and np.ptp(chroma[0]) < 0.05  # one grey, only its lightness varies
    side = np.tile([1.0, 0.0, 0.0], (50, 1))
    q = np.random.default_rng(1).random((50, 3))
    np.testing.assert_array_equal(m["roof"](q, side), m["wall"](q, side))


def test_reference_textures_follow_the_seed_and_cover_every_part():
    v = np.vstack([SQUARE_V, SQUARE_V + [0, 0, 1]])
    f = np.vstack([SQUARE_F, SQUARE_F + 4])
    uv, labels = np.vstack([SQUARE_UV, SQUARE_UV]), np.array([0, 0, 1, 1])
    one = reference_textures("cup", v, f, labels, uv, seed=1, size=32)
    assert sorted(one) == [0, 1] and all(t.shape == (32, 32, 3) and np.isfinite(t).all() for t in one.values())
    again = reference_textures("cup", v, f, labels, uv, seed=1, size=32)
    other = reference_textures("cup", v, f, labels, uv, seed=2, size=32)
    assert all(np.array_equal(one[k], again[k]) for k in one)
    assert not all(np.array_equal(one[k], other[k]) for k in one)
    house = reference_textures("building", v, f, labels, uv, 1, {0: "wall", 1: "roof"}, size=32)
    assert sorted(house) == [0, 1] and not np.array_equal(house[0], house[1])
