"""The buildings generator: its discrete structure (floors, windows, entrances, roofs), parts per
level of detail, sizes, and the Jacobian of the facade details (the generic properties, closed
meshes and the Jacobian at level 0, are in test_generators.py)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ipm.generators import get_generator
from ipm.generators.buildings import BALCONIES, DOOR, FLAT, FRAMES, GABLE, HIP, ROOF, WALLS, WINDOWS
from tests.test_generators import central_difference

BOX = 12  # triangles per box


@pytest.fixture(scope="module")
def gen():
    return get_generator("buildings")


def _with(gen, base: str, **values) -> np.ndarray:
    return gen.spec.from_dict(values, gen.presets[base])


def _count(mesh, part: int) -> int:
    return int(np.sum(mesh.labels == part))


def test_layout_has_many_valued_discrete_parameters(gen):
    spec = gen.spec
    assert 45 <= len(spec) <= 80  # the authors' generator has about 55; wings add their own
    levels = {n: int(spec.upper[i] - spec.lower[i]) + 1 for n, i in spec.index.items() if spec.discrete[i]}
    assert levels["floors"] == 8 and levels["windows_front"] == 9 and levels["roof_type"] == 9
    assert levels["template"] == 4 and levels["annex"] == 2 and levels["wing3_roof"] == 9
    assert gen.part_names == ("walls", "windows", "frames", "roof", "door", "balconies")


def test_windows_and_doors_follow_the_counts(gen):
    x = _with(gen, "house", floors=3, windows_front=2, windows_back=4, windows_left=1, windows_right=0,
              entrances=2)
    m = gen.mesh(x, 2)
    assert _count(m, WINDOWS) == 3 * (2 + 4 + 1 + 0) * BOX  # one glass pane per window and floor
    assert _count(m, DOOR) == 2 * BOX
    fewer = gen.mesh(gen.spec.from_dict({"windows_back": 1}, x), 2)
    assert _count(fewer, WINDOWS) == 3 * (2 + 1 + 1) * BOX


@pytest.mark.slow
def test_levels_of_detail_add_parts(gen):
    x = gen.presets["villa"]
    parts = [set(np.unique(gen.mesh(x, lod).labels)) for lod in gen.lods]
    assert parts[0] == {WALLS, ROOF}
    assert BALCONIES in parts[1] and WINDOWS not in parts[1]
    assert {WINDOWS, DOOR} <= parts[2] and FRAMES not in parts[2]
    assert parts[3] == {WALLS, WINDOWS, FRAMES, ROOF, DOOR, BALCONIES}


@pytest.mark.parametrize("roof", [FLAT, GABLE, HIP])
def test_height_is_floors_and_roof(gen, roof):
    x = _with(gen, "house", floors=4, roof_type=roof, chimney=0, floor_height=0.3, ground_extra=0.05,
              roof_height=0.4, roof_thickness=0.05, roof_overhang=0.1)
    m = gen.mesh(x, 0)
    top = 4 * 0.3 + 0.05
    expected = top + (0.05 if roof == FLAT else 0.4)
    assert m.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-6)
    assert m.vertices[:, 1].max() == pytest.approx(expected, abs=1e-5)
    assert np.abs(m.vertices[:, 0]).max() == pytest.approx(0.5 * x[gen.spec.index["width"]] + 0.1, abs=1e-5)
    roof_y = m.vertices[m.faces[m.labels == ROOF]].reshape(-1, 3)[:, 1]
    assert roof_y.min() == pytest.approx(top, abs=1e-5)


@pytest.mark.parametrize("roof", [GABLE, HIP])
def test_split_roof_shares_the_height_out_anew(gen, roof):
    """A pitched roof takes the share of the height asked, the storeys the rest: the house is as
    tall as before, the floor height takes up the change or, out of its bounds, a storey goes;
    the overhang at least a third of its range. A flat roof has no split."""
    ix = gen.spec.index
    x = _with(gen, "house", floors=2, roof_type=roof, chimney=0, floor_height=0.4, ground_extra=0.05,
              roof_height=0.2, roof_overhang=0.0)
    top = gen.mesh(x, 0).vertices[:, 1].max()
    for share, floors in ((0.3, 2), (0.6, 1)):
        y = gen.split_roof(x, share)
        assert y[ix["floors"]] == floors and gen.spec.lower[ix["floor_height"]] <= y[ix["floor_height"]] <= 0.45
        assert y[ix["roof_height"]] == pytest.approx(share * 1.05)
        assert gen.mesh(y, 0).vertices[:, 1].max() == pytest.approx(top, abs=1e-5)
        assert y[ix["roof_overhang"]] == pytest.approx(0.05)
        assert y[ix["width"]] == x[ix["width"]] and y[ix["windows_front"]] == x[ix["windows_front"]]
    assert gen.split_roof(_with(gen, "house", roof_type=FLAT), 0.5) is None
    assert "roof" not in get_generator("dishes").moves  # a cup has no roof to race


def test_inert_parameters_depend_on_the_structure(gen):
    ix = gen.spec.index
    flat = gen.active(_with(gen, "townhouse", chimney=0))
    assert not flat[ix["roof_height"]] and flat[ix["parapet_height"]] and not flat[ix["chimney_x"]]
    gable = gen.active(gen.presets["house"])
    assert gable[ix["roof_height"]] and not gable[ix["hip_ratio"]] and gable[ix["chimney_x"]]


@pytest.mark.slow
def test_facade_jacobian_matches_central_differences(gen):
    """Level 2 (windows and doors in recesses): the window and door sizes move the right vertices."""
    x = gen.presets["house"].astype(np.float64)
    f = gen.positions_fn(gen.topology_key(x), 2)
    jac = np.asarray(jax.jacfwd(f)(jnp.asarray(x, jnp.float32)))
    span = gen.spec.upper - gen.spec.lower
    for name in ("window_width", "window_height", "window_sill", "window_inset", "window_margin",
                 "door_width", "door_height", "step_height", "floor_height"):
        i = gen.spec.index[name]
        fd = central_difference(f, x, i, 1e-3 * span[i])
        assert np.abs(fd).max() > 0.1, name  # the parameter moves something at this level
        assert np.abs(jac[..., i] - fd).max() < 2e-2 * np.abs(fd).max(), name
