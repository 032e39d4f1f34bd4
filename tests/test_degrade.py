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
