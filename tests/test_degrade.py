"""Mask degradations on analytic shapes: each moves the edge, cuts the hole or drops the part it says."""
import numpy as np
import pytest

from ipm.degrade import DEGRADATIONS, degrade, drop_thin, hole, ragged_edge, shift_edge


def disk(radius: float, size: int = 256, centre=(128.0, 128.0)) -> np.ndarray:
    y, x = np.mgrid[:size, :size] + 0.5
    return (x - centre[0]) ** 2 + (y - centre[1]) ** 2 <= radius**2


@pytest.mark.parametrize("pixels", [-4, -2, -1, 1, 2, 4])
def test_a_moved_edge_gives_the_disk_of_the_moved_radius(pixels):
    out = shift_edge(disk(40.0), pixels)
    assert out.sum() == pytest.approx(np.pi * (40.0 + pixels) ** 2, rel=0.03)
    assert (out >= disk(40.0)).all() if pixels > 0 else (out <= disk(40.0)).all()


def test_a_ragged_edge_moves_the_edge_both_ways_by_about_its_amplitude():
    mask = disk(60.0)
    out = ragged_edge(mask, 2.0, np.random.default_rng(0))
    assert (out & ~mask).any() and (mask & ~out).any()
    assert not (out & ~shift_edge(mask, 10)).any() and not (mask & ~out & shift_edge(mask, -10)).any()
    np.testing.assert_array_equal(out, ragged_edge(mask, 2.0, np.random.default_rng(0)))  # seeded


def test_a_ragged_edge_keeps_the_area():
    mask = disk(60.0)
    for seed in range(4):
        out = ragged_edge(mask, 2.0, np.random.default_rng(seed))
        assert out.sum() == mask.sum()  # moved as far out as in, not inwards by the rounding
        assert 0.9 < (out & mask).sum() / (out | mask).sum() < 0.99
    np.testing.assert_array_equal(ragged_edge(mask, 1e-9, np.random.default_rng(0)), mask)


def test_a_hole_is_cut_at_the_deepest_point_inside_the_mask():
    mask = disk(40.0)
    out = hole(mask, 0.5)
    assert (out <= mask).all() and not out[128, 128]
    assert (mask.sum() - out.sum()) == pytest.approx(np.pi * 20.0**2, rel=0.05)


def test_a_thin_part_and_what_it_cut_off_are_dropped():
    body = disk(40.0)
    bar = np.zeros_like(body)
    bar[126:130, 168:220] = True  # 4 px wide, out from the body's right side
    tip = disk(6.0, centre=(226.0, 128.0))  # a knob on its end, cut off with it
    out = drop_thin(body | bar | tip, 10.0)
    assert not (out & (bar | tip) & ~shift_edge(body, 3)).any()  # but the fillet where it joined
    assert out[body].mean() > 0.99


def test_every_named_degradation_keeps_the_shape_and_size():
    mask = disk(50.0)
    for name in DEGRADATIONS:
        out = degrade(mask, name, np.random.default_rng(1))
        assert out.shape == mask.shape and out.dtype == bool and out.any()
        assert (out & mask).sum() / (out | mask).sum() > 0.7


def test_unknown_names_and_emptied_masks_are_errors():
    with pytest.raises(ValueError, match="unknown mask degradation"):
        degrade(disk(20.0), "blur", np.random.default_rng(0))
    with pytest.raises(ValueError, match="empty mask"):
        degrade(disk(3.0), "edge -4 px", np.random.default_rng(0))


def test_pixel_amounts_scale_with_the_image_width():
    """'edge +2 px' is 2 px at 256 px wide: 1 px on a 128 px mask (the same share of the object)."""
    small = disk(40.0, size=128, centre=(64.0, 64.0))
    np.testing.assert_array_equal(degrade(small, "edge +2 px", np.random.default_rng(0)), shift_edge(small, 1))
    np.testing.assert_array_equal(degrade(disk(40.0), "edge +2 px", np.random.default_rng(0)), shift_edge(disk(40.0), 2))


def test_the_edge_shift_is_read_from_the_name():
    from ipm.degrade import edge_shift

    assert [edge_shift(n) for n in ("none", "edge -2 px", "edge +4 px", "hole")] == [0.0, -2.0, 4.0, None]


def test_names_and_their_words_go_both_ways():
    from ipm.degrade import by_slug, slug

    words = [slug(name) for name in DEGRADATIONS]
    assert len(set(words)) == len(words) and all(w.isalnum() and w.islower() for w in words)
    assert slug("edge +2 px") == "edgep2px" and slug("edge -2 px") == "edgem2px"
    assert [by_slug(w) for w in words] == list(DEGRADATIONS)
    with pytest.raises(ValueError, match="no mask degradation is called 'blur'"):
        by_slug("blur")


def _views(folder, masks):
    """A views folder with one mask per view (and no other images)."""
    import json

    from ipm.io.views import save_mask

    frames = []
    for i, m in enumerate(masks):
        save_mask(folder / "masks" / f"{i:03d}.png", m)
        frames.append({"file_path": f"masks/{i:03d}.png", "mask_path": f"masks/{i:03d}.png",
                       "transform_matrix": np.eye(4).tolist()})
    (folder / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": frames}))
    return folder


def test_degraded_views_copy_the_folder_and_degrade_every_mask(tmp_path):
    """Each view's mask is degraded with its own draw (view i from the seed and i), the true folder
    is left as it was, and degradation.json records the name, the seed and each mask's IoU."""
    import json

    from PIL import Image

    from ipm.degrade import degrade_views

    src = _views(tmp_path / "src", [disk(50.0), disk(40.0, centre=(100.0, 140.0))])
    ious = degrade_views(src, tmp_path / "out", "ragged 2 px", seed=3)
    read = lambda p: np.asarray(Image.open(p)) > 127  # noqa: E731
    for i, true in enumerate([disk(50.0), disk(40.0, centre=(100.0, 140.0))]):
        np.testing.assert_array_equal(read(src / f"masks/{i:03d}.png"), true)
        expected = degrade(true, "ragged 2 px", np.random.default_rng([3, i]))
        np.testing.assert_array_equal(read(tmp_path / f"out/masks/{i:03d}.png"), expected)
        assert ious[i] == pytest.approx((expected & true).sum() / (expected | true).sum(), abs=1e-4)
    record = json.loads((tmp_path / "out/degradation.json").read_text())
    assert record == {"degradation": "ragged 2 px", "seed": 3, "mask_iou": ious} and 0.8 < min(ious) < 1.0


def test_a_degradation_that_fails_leaves_nothing_behind(tmp_path):
    from ipm.degrade import degrade_views
    from ipm.errors import UserError

    src = _views(tmp_path / "src", [disk(50.0), disk(3.0)])
    with pytest.raises(UserError, match="view 1: the degradation 'edge -4 px' leaves an empty mask"):
        degrade_views(src, tmp_path / "out", "edge -4 px", seed=0)
    assert not (tmp_path / "out").exists()
    with pytest.raises(UserError, match="no views to degrade"):
        degrade_views(tmp_path / "missing", tmp_path / "out", "hole", seed=0)
