"""The diffSDF-style baseline, stage by stage: soft silhouettes of an analytic sphere, the loss
gradient against finite differences, the field helpers, a smoke run and bad input."""
from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.diffsdf import PROFILES, loss, run_diffsdf, stage_data
from baselines.diffsdf import field as fieldlib
from baselines.diffsdf.render import closest_approach, image_stack, pyramid, silhouettes, trilinear
from ipm.errors import UserError
from ipm.io import load_mesh
from ipm.io.views import Views, resize_masks
from ipm.methods import METHODS, resolve
from ipm.render.cameras import orbit_camera

LO, HI = np.array([-0.6, -0.5, -0.6]), np.array([0.6, 0.8, 0.6])
CENTRE, RADIUS = 0.5 * (LO + HI), 0.4  # the world sphere used below (L = 1.3)
FOV = 0.7


def _views(n: int, res: int) -> Views:
    c2w = np.stack([orbit_camera(CENTRE, 3.0, 360.0 * k / n + 10.0, 25.0 - 40.0 * (k % 2)) for k in range(n)])
    return Views(FOV, res, res, c2w, np.zeros((n, res, res), np.float32))


def _analytic_disc(views: Views) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel centre: whether its ray meets the sphere, and the ray's distance to its centre."""
    f = 0.5 * views.width / np.tan(0.5 * views.fov_x)
    px, py = np.meshgrid(np.arange(views.width) + 0.5, np.arange(views.height) + 0.5)
    d_cam = np.stack([(px - views.width / 2) / f, -(py - views.height / 2) / f, -np.ones_like(px)], -1)
    d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
    dist = []
    for m in views.c2w:
        d = d_cam @ m[:3, :3].T
        oc = CENTRE - m[:3, 3]
        along = d @ oc
        dist.append(np.sqrt(np.maximum(oc @ oc - along ** 2, 0.0)))
    dist = np.stack(dist)
    return dist < RADIUS, dist


def _sphere_grid(n: int) -> np.ndarray:
    shape = fieldlib.grid_shape(LO, HI, n)
    return fieldlib.sphere(LO, HI, shape, RADIUS / float((HI - LO).max()))


def test_silhouette_of_a_sphere_matches_its_projected_disc():
    import jax

    views = _views(3, 48)
    grid = _sphere_grid(40)
    data, n_samples = stage_data(views, views.masks, LO, HI, grid.shape, 1, PROFILES["default"].step)
    tmin = closest_approach(grid, data["origin"], data["direction"], data["t0"], data["t1"],
                            jax.numpy.full(data["t0"].shape, 0.5), n_samples, PROFILES["default"].refine)
    sil = np.asarray(image_stack(silhouettes(grid, (data["origin"], data["direction"], data["footprint"]),
                                             tmin, 0.25), data["pixel"], views.masks.shape))
    disc, dist = _analytic_disc(views)
    pixel = 3.0 * np.tan(0.5 * FOV) / (0.5 * views.width)  # world pixel size at the sphere's distance
    rim = np.abs(dist - RADIUS) < pixel
    pred = sil > 0.5
    iou = (pred & disc).sum() / (pred | disc).sum()
    assert iou > 0.97
    assert not (pred != disc)[~rim].any()  # disagreements only within a pixel of the rim
    assert sil[disc & ~rim].min() > 0.95 and sil[~disc & ~rim].max() < 0.05
    assert 0.15 < sil[rim].mean() < 0.85  # the rim is soft, not binary
    # the closest approach of a missing ray is the sphere's distance from it (an SDF of L units)
    u = data["origin"] + tmin[:, None] * data["direction"]
    f = np.asarray(trilinear(grid, u)) * float((HI - LO).max())
    miss = np.asarray(disc.reshape(-1)[np.asarray(data["pixel"])] == 0)
    expected = dist.reshape(-1)[np.asarray(data["pixel"])][miss] - RADIUS
    near = expected < 0.1
    assert np.abs(f[miss][near] - expected[near]).max() < 0.02


def test_loss_gradient_matches_central_differences():
    import jax
    import jax.numpy as jnp

    views = _views(2, 16)
    disc, _ = _analytic_disc(views)
    views = Views(views.fov_x, 16, 16, views.c2w, disc.astype(np.float32))
    grid = _sphere_grid(8) * 1.3 + 0.02  # not the target, so the image term has a gradient
    data, n_samples = stage_data(views, views.masks, LO, HI, grid.shape, 3, 0.75)
    tmin = closest_approach(grid, data["origin"], data["direction"], data["t0"], data["t1"],
                            jnp.full(data["t0"].shape, 0.3), n_samples)
    with jax.enable_x64(True):
        data64 = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64) if x.dtype == jnp.float32 else x, data)
        g64, t64 = jnp.asarray(grid, jnp.float64), jnp.asarray(tmin, jnp.float64)

        def total(g):
            return loss(g, data64, t64, 1.0, views.masks.shape, 3, 1e-3)[0]

        total = jax.jit(total)
        grad = np.asarray(jax.grad(total)(g64))
        flat = np.abs(grad).reshape(-1)
        rng = np.random.default_rng(0)
        picks = np.concatenate([np.argsort(flat)[-8:], rng.choice(flat.size, 8, replace=False)])
        eps = 1e-6
        for i in picks:
            e = np.zeros(grid.size)
            e[i] = eps
            e = jnp.asarray(e.reshape(grid.shape))
            fd = (float(total(g64 + e)) - float(total(g64 - e))) / (2 * eps)
            assert fd == pytest.approx(grad.reshape(-1)[i], rel=1e-4, abs=1e-9)
    assert flat.max() > 1e-4  # the image term does reach the grid


def test_field_helpers_keep_the_surface():
    shape = fieldlib.grid_shape(LO, HI, 32)
    assert max(shape) == 32 and shape[0] == shape[2] < 32
    sdf = _sphere_grid(32)
    spacing = (HI - LO) / np.asarray(shape) / float((HI - LO).max())
    stretched = 2.5 * sdf  # same surface, wrong distances
    redone = fieldlib.redistance(stretched, spacing)
    keep = fieldlib.surface_cells(sdf)
    assert 0 < keep.sum() < 0.2 * sdf.size
    assert np.array_equal(redone[keep], stretched[keep])  # the trilinear surface does not move
    assert np.array_equal(redone > 0, sdf > 0)
    assert np.abs(redone - sdf)[~keep].max() < 0.6 * spacing.max()  # distances again elsewhere
    assert np.median(np.abs(redone - sdf)[~keep]) < 0.1 * spacing.max()
    up = fieldlib.upsample(sdf)
    assert up.shape == tuple(2 * s for s in shape)
    # trilinear between old cell centres: a linear field stays linear away from the edges
    i, j, k = np.indices((8, 8, 8), dtype=np.float32)
    lin = fieldlib.upsample(1.0 * i - 2.0 * j + 0.5 * k)
    ui, uj, uk = (np.indices((16, 16, 16)) + 0.5) / 2 - 0.5
    inner = (slice(1, -1),) * 3
    assert np.allclose(lin[inner], (ui - 2 * uj + 0.5 * uk)[inner], atol=1e-5)
    masks = np.zeros((1, 8, 8), np.float32)
    masks[0, :4, :2] = 1
    small = resize_masks(masks, 4)
    assert small.shape == (1, 4, 4) and small[0, 0, 0] == 1 and small.sum() == masks.sum() / 4
    levels = pyramid(np.random.default_rng(0).random((2, 12, 10)), 4)
    assert [p.shape for p in levels] == [(2, 12, 10), (2, 6, 5), (2, 3, 2), (2, 1, 1)]
    assert levels[1].mean() == pytest.approx(levels[0].mean()) and levels[1][1, 2, 3] == pytest.approx(
        levels[0][1, 4:6, 6:8].mean())


@pytest.fixture(scope="module")
def tiny3(tmp_path_factory, mitsuba_cpu):
    """cup_1 rendered at 48 px with 3 views."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("synth3") / "cup_1"
    synthesize("cup_1", out, n_views=3, res=48, spp=4, progress=False)
    return out


@pytest.mark.slow
def test_smoke_run_writes_a_watertight_mesh_near_the_object(tmp_path, tiny3):
    from ipm.metrics import silhouette_iou

    assert resolve(METHODS["diffsdf"].entry) is run_diffsdf and "diffSDF" in METHODS["diffsdf"].label
    info = run_diffsdf(tiny3 / "transforms.json", tmp_path / "a", profile="smoke", seed=1, progress=False)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["info.json", "mesh.ply", "timing.json"]
    assert json.loads((tmp_path / "a" / "info.json").read_text())["views"] == 3 == info["views"]
    mesh = load_mesh(tmp_path / "a" / "mesh.ply")
    assert mesh.is_watertight and np.isfinite(mesh.vertices).all() and len(mesh.faces) > 100
    lo, hi = (np.array(b) for b in info["box"])
    assert (mesh.vertices >= lo - 1e-6).all() and (mesh.vertices <= hi + 1e-6).all()
    ref = load_mesh(tiny3 / "reference.ply")
    assert silhouette_iou(ref, mesh, n_views=8, res=48)["iou_mean"] > 0.75
    assert info["stage_image_loss"][-1] < info["stage_image_loss"][0]  # finer stages fit the masks better
    # the same seed gives the same mesh
    run_diffsdf(tiny3 / "transforms.json", tmp_path / "b", profile="smoke", seed=1, progress=False)
    assert np.array_equal(load_mesh(tmp_path / "b" / "mesh.ply").vertices, mesh.vertices)


def test_bad_input_is_a_user_error(tmp_path, tiny3):
    with pytest.raises(UserError, match="views"):
        run_diffsdf(tiny3 / "transforms.json", tmp_path / "x", profile="smoke", n_input_views=1, progress=False)
    with pytest.raises(UserError, match="unknown profile"):
        run_diffsdf(tiny3 / "transforms.json", tmp_path / "x", profile="fast", progress=False)
    assert set(PROFILES) == {"smoke", "default", "paper"}
    assert not (tmp_path / "x").exists()
