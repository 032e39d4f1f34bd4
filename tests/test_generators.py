"""Generator properties: closed, consistently oriented, finite meshes; Jacobian vs finite differences."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from ipm.errors import UserError
from ipm.generators import GENERATORS, get_generator
from tests.conftest import part_volumes, slow_except

NAMES = GENERATORS.names()


def _check_closed(gen, x, lod):
    m = gen.mesh(x, lod)
    assert np.all(np.isfinite(m.vertices)) and np.all(np.isfinite(m.normals))
    assert m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
    assert len(m.labels) == len(m.faces) and m.uv.shape == (len(m.faces), 3, 2)
    assert set(np.unique(m.labels)) <= set(range(len(m.part_names)))
    t = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert t.is_watertight and t.is_winding_consistent
    assert np.all(part_volumes(t) > 0)  # every part outward: Mitsuba's area emitters are one-sided
    return m


@pytest.mark.parametrize("name", slow_except(NAMES, "dishes"))
def test_presets_are_closed_at_every_lod(name):
    gen = get_generator(name)
    assert gen.presets
    for x in gen.presets.values():
        assert np.all(x >= gen.spec.lower) and np.all(x <= gen.spec.upper)
        for lod in gen.lods:
            _check_closed(gen, x, lod)


@pytest.mark.parametrize("name", slow_except(NAMES, "dishes", "buildings"))
def test_random_parameters_give_closed_meshes(name, rng):
    gen = get_generator(name)
    for _ in range(8):
        _check_closed(gen, gen.spec.from_unit(rng.random(len(gen.spec))), min(gen.lods))


@pytest.mark.parametrize("name", slow_except(NAMES, "dishes", "trees"))
def test_level_of_detail_adds_triangles(name):
    gen = get_generator(name)
    x = next(iter(gen.presets.values()))
    counts = [len(gen.mesh(x, lod).faces) for lod in gen.lods]
    assert counts == sorted(counts) and counts[0] < counts[-1]


def central_difference(f, x: np.ndarray, i: int, h: float) -> np.ndarray:
    """(f(x + h e_i) - f(x - h e_i)) / 2h for a positions function ``f`` (float32 in, arrays out)."""
    xp, xm = x.copy(), x.copy()
    xp[i] += h
    xm[i] -= h
    return (np.asarray(f(jnp.asarray(xp, jnp.float32)), np.float64)
            - np.asarray(f(jnp.asarray(xm, jnp.float32)), np.float64)) / (2 * h)


@pytest.mark.parametrize("name", slow_except([n for n in NAMES if GENERATORS[n].differentiable], "dishes"))
def test_jacobian_matches_central_differences(name, rng):
    gen = get_generator(name)
    x = next(iter(gen.presets.values())).astype(np.float64)
    key = gen.topology_key(x)
    f = gen.positions_fn(key, min(gen.lods))
    jac = np.asarray(jax.jacfwd(f)(jnp.asarray(x, jnp.float32)))  # (V, 3, n)
    span = gen.spec.upper - gen.spec.lower
    cont = np.nonzero(~gen.spec.discrete)[0]
    for i in rng.choice(cont, size=min(12, len(cont)), replace=False):
        fd = central_difference(f, x, i, 1e-3 * span[i])
        scale = max(np.abs(fd).max(), 1e-3)
        assert np.abs(jac[..., i] - fd).max() < 2e-2 * scale, gen.spec.names[i]
    for i in np.nonzero(gen.spec.discrete)[0]:
        assert np.all(jac[..., i] == 0.0)  # discrete parameters have zero derivative


def test_dishes_follows_the_authors_layout():
    gen = get_generator("dishes")
    assert len(gen.spec) == 53
    assert gen.spec.names[:9] == tuple(f"profile_{i}" for i in range(9))
    assert list(gen.spec.discrete.nonzero()[0]) == [gen.spec.index["has_handle"]]
    assert set(gen.presets) == {"mug", "tea_cup", "bowl", "jar"}
    mug, bowl = gen.mesh(gen.presets["mug"], 0), gen.mesh(gen.presets["bowl"], 0)
    assert set(np.unique(mug.labels)) == {0, 1} and set(np.unique(bowl.labels)) == {0}
    assert mug.part_names == ("body", "handle")
    assert abs(mug.vertices[:, 1].min()) < 1e-6  # stands on y = 0


def test_spec_round_trip_and_errors():
    spec = get_generator("dishes").spec
    x = spec.default
    np.testing.assert_allclose(spec.from_unit(spec.to_unit(x)), x, atol=1e-12)
    assert spec.from_dict(spec.as_dict(x)).tolist() == x.tolist()
    with pytest.raises(UserError, match="unknown parameter"):
        spec.from_dict({"nope": 1.0})
    with pytest.raises(UserError, match="not finite"):
        spec.from_dict({"y_scale": float("nan")})
    with pytest.raises(UserError, match="unknown generator"):
        get_generator("teapot")


def test_registry_refuses_duplicates():
    with pytest.raises(KeyError, match="already registered"):
        GENERATORS.register("dishes")(object)


def test_smoothness_prior_gradient_matches_finite_differences(rng):
    from ipm.problem import Problem

    problem = Problem(get_generator("dishes"), np.zeros(3), 1.0)
    z = problem.clip(np.concatenate([rng.random(problem.n_shape), [0.3, 0, 0, 0, 0, 0, 0]]))
    value, grad = problem.regulariser(z, 0.33)
    assert value > 0
    for i in (0, 4, 8, 13, 20, 40, 52):
        e = np.zeros_like(z)
        e[i] = 1e-6
        fd = (problem.regulariser(z + e, 0.33)[0] - problem.regulariser(z - e, 0.33)[0]) / 2e-6
        assert grad[i] == pytest.approx(fd, rel=1e-4, abs=1e-9)
    assert grad[9] == 0.0  # y_scale is not in a smoothed sequence


def test_dish_handle_held_on_the_wall_by_the_search():
    """The dishes' feasible objects: the sampler's and the presets' handles are left as they are; a
    handle reaching below the base or above the rim is drawn in until the tube lies within the
    body's height (to the spline's overshoot between control points), and the search's projection
    moves only those entries."""
    from ipm.generators.dishes import N_HANDLE
    from ipm.problem import Problem

    gen = get_generator("dishes")
    ix, rng = gen.spec.index, np.random.default_rng(0)
    i_h = ix["handle_radius_0"]
    for _ in range(200):
        x = gen.sample(rng, handle=True)
        assert gen.feasible(x) is x
    assert all(gen.feasible(x) is x for x in gen.presets.values())
    moved = 0
    for _ in range(40):
        x = gen.spec.from_unit(rng.random(len(gen.spec)))
        x[ix["has_handle"]] = 1.0
        held = gen.feasible(x)
        assert np.array_equal(np.delete(held, np.s_[i_h:i_h + N_HANDLE]), np.delete(x, np.s_[i_h:i_h + N_HANDLE]))
        assert np.all(held[i_h:i_h + N_HANDLE] <= x[i_h:i_h + N_HANDLE])
        if np.any(held[i_h:i_h + N_HANDLE] <= gen.spec.lower[i_h:i_h + N_HANDLE]):
            continue  # too low a body for any handle: the distances' lower bound wins
        moved += held is not x
        height, mesh = held[ix["y_scale"]], gen.mesh(held, 1, uv=False)
        y = mesh.vertices[np.unique(mesh.faces[mesh.labels == 1])][:, 1]
        assert y.min() > -0.04 * height and y.max() < 1.04 * height
    assert moved > 10
    problem = Problem(gen, np.zeros(3), 1.0)
    x = gen.presets["mug"].copy()
    x[ix["handle_height"]], x[i_h:i_h + N_HANDLE] = 0.3, 0.5
    z = np.concatenate([gen.spec.to_unit(x), np.zeros(problem.dim - problem.n_shape)])
    held = problem.clip(z)
    assert np.array_equal(np.delete(held, np.s_[i_h:i_h + N_HANDLE]), np.delete(z, np.s_[i_h:i_h + N_HANDLE]))
    assert held[i_h] < z[i_h] and np.array_equal(problem.clip(held), held)


def test_dish_inner_wall_stays_inside_where_the_profile_lies_flat():
    """A goblet's foot (the radius falling fast above the base): at every height the inner wall
    lies inside the outer one, so the body does not cross itself."""
    from ipm.generators.dishes import _LOD

    gen = get_generator("dishes")
    x = gen.presets["bowl"].copy()
    x[:9] = [2.7, 0.5, 0.5, 0.3, 0.5, 2.1, 3.1, 3.3, 3.0]
    x[gen.spec.index["y_scale"]] = 1.06
    for lod in gen.lods:
        n_p, n_r = _LOD[lod][:2]
        rows = np.asarray(gen.mesh(x, lod).vertices)[1:1 + 2 * n_p * n_r].reshape(2 * n_p, n_r, 3)
        radius, height = np.hypot(rows[..., 0], rows[..., 2]).mean(1), rows[:, 0, 1]
        outer = np.interp(height[n_p:], height[:n_p], radius[:n_p])
        assert np.all(radius[n_p:] < outer - 1e-3), lod
