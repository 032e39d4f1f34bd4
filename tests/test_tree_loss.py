"""The tree similarity loss (paper, "Tree Similarity Function") and semantic label images."""
from __future__ import annotations


import numpy as np
import pytest
from PIL import Image

from ipm.errors import UserError
from ipm.io.semantic import BACKGROUND, BRANCH, FOLIAGE, labels_from_rgb, load_labels, save_labels
from ipm.losses import (
    LOSSES, REGULARISERS, TreeStats, loss_terms, regularisation_multipliers, stripe_features, tree_loss,
    tree_similarity,
)

RES = 256


def synthetic_tree(cx=128, cy=90, rx=60, ry=60, trunk_x=128, trunk_w=10, trunk_bottom=240, res=RES):
    """Labels of a tree: an ellipse of foliage on a rectangle trunk (rows cy..trunk_bottom)."""
    labels = np.zeros((res, res), np.uint8)
    labels[cy:trunk_bottom, trunk_x - trunk_w // 2:trunk_x + trunk_w // 2] = BRANCH
    yy, xx = np.mgrid[:res, :res]
    labels[((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1] = FOLIAGE
    return labels


def tsim(a, b, **kw):
    return tree_similarity(stripe_features(a, **kw), stripe_features(b, **kw))


@pytest.fixture(scope="module")
def ref():
    return synthetic_tree()


def test_registered_under_tree_similarity():
    assert LOSSES["tree_similarity"] is tree_loss
    assert "tree_similarity" in LOSSES.names()


def test_identical_images_give_tsim_one_and_zero_loss(ref):
    assert tsim(ref, ref.copy()) == 1.0
    assert tree_loss(ref, ref.copy()) == 0.0
    stats = TreeStats(ref, graph_vertices=40, leaf_size=0.03)
    terms = loss_terms(stats, TreeStats(ref.copy(), graph_vertices=40, leaf_size=0.03), REGULARISERS)
    assert terms["loss"] == 0.0 and all(terms[name] == 1.0 for name in REGULARISERS)
    # any other tree scores worse
    assert tree_loss(ref, synthetic_tree(cx=140)) > 0.05


def test_tsim_decreases_as_the_crown_shifts(ref):
    values = [tsim(ref, synthetic_tree(cx=128 + dx)) for dx in (0, 4, 8, 16, 32, 48)]
    assert values[0] == 1.0
    assert all(b < a for a, b in zip(values, values[1:])), values
    assert values[-1] < 0.6


@pytest.mark.parametrize("axes", ["width", "both"])
def test_tsim_decreases_as_the_crown_shrinks(ref, axes):
    values = [tsim(ref, synthetic_tree(rx=r, ry=60 if axes == "width" else r)) for r in (60, 55, 50, 40, 30)]
    assert values[0] == 1.0
    assert all(b < a for a, b in zip(values, values[1:])), values


def test_tsim_is_invariant_to_position_and_nearly_to_scale(ref):
    moved = np.roll(ref, (7, -20), axis=(0, 1))
    assert tsim(ref, moved) == pytest.approx(1.0)
    half = np.zeros_like(ref)
    half[100:228, 50:178] = ref[::2, ::2]
    assert tsim(ref, half) > 0.9  # same shape; only the size differs ...
    terms = loss_terms(ref, half, ["height"])
    assert terms["height"] == pytest.approx(0.5)  # ... which the height multiplier sees
    assert terms["loss"] == pytest.approx(1 - terms["tsim"] * 0.5)


def test_trunk_and_crown_stripes_are_classified(ref):
    f = stripe_features(ref, stripe_height=16)
    assert f.n_stripes == RES // 16
    top, bottom = f.bbox[:2]
    assert (top, bottom) == (30, 240)
    bounds = top + -((-np.arange(f.n_stripes + 1) * (bottom - top)) // f.n_stripes)
    crown_bottom = 150  # ellipse rows 30..150, trunk alone below
    for i in range(f.n_stripes):
        if bounds[i + 1] <= crown_bottom:
            assert not f.trunk[i], i
            assert f.leaf_share[i] > f.branch_share[i]
        elif bounds[i] >= crown_bottom:
            assert f.trunk[i], i
            assert f.leaf_share[i] == 0.0
    assert f.trunk.sum() >= 6 and (~f.trunk).sum() >= 8
    assert not f.empty.any()


def test_borders_are_ordered_and_in_object_heights(ref):
    rng = np.random.default_rng(0)
    noisy = ref.copy()
    noisy[rng.random(ref.shape) < 0.2] = BACKGROUND  # holes thin out the dense crown
    for labels in (ref, noisy, synthetic_tree(cx=100, rx=30, ry=80)):
        f = stripe_features(labels)
        assert np.all(f.a <= f.b) and np.all(f.b <= f.c) and np.all(f.c <= f.d)
    f = stripe_features(ref)
    h = f.height
    # the trunk is 10 px wide, centred on the root: [-5, 5] px
    trunk = np.flatnonzero(f.trunk)[-1]
    assert f.a[trunk] == pytest.approx(-5 / h) and f.d[trunk] == pytest.approx(5 / h)
    # crown stripes through the ellipse's middle: crown about 2 rx wide, dense crown inside
    mid = np.argmax(f.d - f.a)
    assert (f.d[mid] - f.a[mid]) * h == pytest.approx(121, abs=2)
    assert f.c[mid] - f.b[mid] > 0.9 * (f.d[mid] - f.a[mid])


def test_dense_crown_needs_more_than_75_percent_foliage():
    labels = np.zeros((32, 32), np.uint8)
    labels[:16, 4:28] = BRANCH
    labels[:12, 10:14] = FOLIAGE  # 12 of 16 rows: exactly 75 %, not dense
    labels[:13, 20:22] = FOLIAGE  # 13 of 16 rows: dense
    f = stripe_features(labels, n_stripes=1)
    h = f.height
    assert (f.a[0] * h + f.root_x, f.d[0] * h + f.root_x) == pytest.approx((4, 28))
    assert (f.b[0] * h + f.root_x, f.c[0] * h + f.root_x) == pytest.approx((20, 22))


def test_multipliers_are_one_for_equal_stats_and_min_over_max_otherwise(ref):
    a = TreeStats(ref, graph_vertices=40, leaf_size=0.02)
    assert regularisation_multipliers(a, a, REGULARISERS) == {name: 1.0 for name in REGULARISERS}
    taller = synthetic_tree(cy=60, trunk_bottom=250)
    b = TreeStats(taller, graph_vertices=50, leaf_size=0.05)
    fa, fb = a.features(), b.features()
    m = regularisation_multipliers(a, b, {"graph_vertices": True, "leaf_size": True, "height": True,
                                          "width": False, "branch_density": True, "leaf_density": True})
    assert set(m) == {"graph_vertices", "leaf_size", "height", "branch_density", "leaf_density"}
    assert m["graph_vertices"] == pytest.approx(40 / 50)
    assert m["leaf_size"] == pytest.approx(0.02 / 0.05)
    assert m["height"] == pytest.approx(210 / 250)
    assert m["branch_density"] == pytest.approx(min(fa.branch_density, fb.branch_density)
                                                / max(fa.branch_density, fb.branch_density))
    assert m["leaf_density"] < 1.0
    terms = loss_terms(a, b, list(m))
    assert terms["loss"] == pytest.approx(1.0 - terms["tsim"] * np.prod(list(m.values())))
    assert regularisation_multipliers(a, b) == {}  # none by default


def test_similarity_and_loss_are_symmetric(ref):
    others = [synthetic_tree(cx=150, rx=45), synthetic_tree(cy=60, ry=40, trunk_w=16), synthetic_tree(trunk_x=110)]
    for other in others:
        f, g = stripe_features(ref), stripe_features(other)
        assert tree_similarity(f, g) == pytest.approx(tree_similarity(g, f), abs=1e-12)
        a, b = TreeStats(ref, graph_vertices=30), TreeStats(other, graph_vertices=45)
        regs = ["graph_vertices", "height", "width", "branch_density", "leaf_density"]
        assert tree_loss(a, b, regs) == pytest.approx(tree_loss(b, a, regs), abs=1e-12)


def test_small_objects_leave_empty_stripes_without_failing(ref):
    tiny = np.zeros_like(ref)
    tiny[100:105, 100:103] = FOLIAGE
    tiny[104, 101] = BRANCH
    f = stripe_features(tiny)
    assert f.empty.sum() == f.n_stripes - 5
    assert 0.0 <= tsim(ref, tiny) < 0.5


def test_bad_input_is_a_user_error(ref):
    empty = np.zeros_like(ref)
    with pytest.raises(UserError, match="empty label image"):
        stripe_features(empty)
    with pytest.raises(UserError, match="empty label image"):
        tree_loss(ref, empty)
    with pytest.raises(UserError, match="differ in size"):
        tree_loss(ref, ref[:128])
    with pytest.raises(UserError, match="uint8"):
        stripe_features(ref.astype(np.int64))
    with pytest.raises(UserError, match=r"\(H, W\)"):
        stripe_features(np.stack([ref, ref], axis=-1))
    with pytest.raises(UserError, match="not a label"):
        stripe_features(ref * 3)
    with pytest.raises(UserError, match="stripe counts differ"):
        tree_similarity(stripe_features(ref, n_stripes=20), stripe_features(ref, n_stripes=24))
    with pytest.raises(UserError, match="unknown regulariser"):
        tree_loss(ref, ref, ["crown_volume"])
    with pytest.raises(UserError, match="graph_vertices"):
        tree_loss(TreeStats(ref, graph_vertices=10), TreeStats(ref), ["graph_vertices"])
    with pytest.raises(UserError, match="n_stripes"):
        stripe_features(ref, n_stripes=0)


def synthetic_photo(rng):
    """White backdrop, brown trunk, a grey branch and a noisy green crown; and its true labels."""
    truth = synthetic_tree()
    truth[120:124, 60:128] = BRANCH  # a grey branch under the crown's left edge
    truth[((np.mgrid[:RES, :RES][1] - 128) / 60) ** 2 + ((np.mgrid[:RES, :RES][0] - 90) / 60) ** 2 <= 1] = FOLIAGE
    rgb = np.full((RES, RES, 3), 250, np.float64)
    rgb[truth == BRANCH] = (110, 75, 40)
    rgb[120:124, 60:128][truth[120:124, 60:128] == BRANCH] = (120, 120, 118)
    shade = rng.uniform(0.5, 1.2, size=(RES, RES, 1))
    leaves = np.array([60, 140, 50]) * shade
    rgb[truth == FOLIAGE] = leaves[truth == FOLIAGE]
    rgb += rng.normal(0, 6, rgb.shape)
    return np.clip(rgb, 0, 255).astype(np.uint8), truth


def test_labels_from_rgb_recovers_a_synthetic_tree():
    rgb, truth = synthetic_photo(np.random.default_rng(1))
    labels = labels_from_rgb(rgb)
    assert labels.dtype == np.uint8 and labels.shape == truth.shape
    assert (labels == truth).mean() > 0.95
    for value in (BACKGROUND, BRANCH, FOLIAGE):  # each class on its own, not only the background
        assert (labels[truth == value] == value).mean() > 0.95
    with_mask = labels_from_rgb(rgb.astype(np.float32) / 255, mask=(truth != 0).astype(np.uint8) * 255)
    assert np.array_equal(with_mask != 0, truth != 0)
    assert (with_mask == truth).mean() > 0.97
    with pytest.raises(UserError, match="does not match"):
        labels_from_rgb(rgb, mask=np.ones((10, 10)))
    with pytest.raises(UserError, match="shape"):
        labels_from_rgb(rgb[..., 0])


def test_labels_png_round_trip_and_checks(tmp_path, ref):
    path = tmp_path / "semantic" / "000.png"
    save_labels(path, ref)
    assert sorted(p.name for p in path.parent.iterdir()) == ["000.png"]  # no temporary left behind
    assert Image.open(path).mode == "L"
    back = load_labels(path, RES, RES)
    assert back.dtype == np.uint8 and np.array_equal(back, ref)
    with pytest.raises(UserError, match="expected 128x256"):
        load_labels(path, 128, RES)
    with pytest.raises(UserError, match="not found"):
        load_labels(tmp_path / "missing.png", RES, RES)
    Image.fromarray(ref * 100).save(tmp_path / "bad.png")
    with pytest.raises(UserError, match="not a label"):
        load_labels(tmp_path / "bad.png", RES, RES)
    Image.fromarray(np.stack([ref] * 3, axis=-1)).save(tmp_path / "rgb.png")
    with pytest.raises(UserError, match="single-channel"):
        load_labels(tmp_path / "rgb.png", RES, RES)
    with pytest.raises(UserError, match="not a label"):
        save_labels(tmp_path / "x.png", ref + 5)
    assert not (tmp_path / "x.png").exists()
