"""The instant-NGP-style baseline, part by part: the hash encoding (indexing, continuity, gradient),
volume rendering of an analytic sphere, the occupancy grid, a smoke run and bad input."""
from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.ngp import PROFILES, run_ngp
from baselines.ngp import encoding as enc
from baselines.ngp import render
from ipm.errors import UserError
from ipm.io import load_mesh
from ipm.methods import METHODS, resolve

GRID = enc.HashGrid(levels=4, log2_table=12, features=2, n_min=4, n_max=32)
"""Levels of resolution 4, 8, 16, 32: the first two dense ((N + 1)^3 <= 4096), the others hashed."""


def test_levels_are_geometric_dense_levels_index_every_corner_once_hashed_ones_stay_in_the_table():
    import jax.numpy as jnp

    assert GRID.resolutions().tolist() == [4, 8, 16, 32]
    assert GRID.dense().tolist() == [True, True, False, False]
    paper = enc.HashGrid(levels=16, n_min=16, n_max=512)
    res = paper.resolutions()
    assert res[0] == 16 and res[-1] == 512 and np.all(np.diff(res) > 0)
    for res, dense in zip(GRID.resolutions(), GRID.dense()):
        corners = np.stack(np.meshgrid(*(np.arange(res + 1),) * 3, indexing="ij"), -1).reshape(-1, 3)
        idx = np.asarray(enc.corner_index(jnp.asarray(corners), int(res), bool(dense), GRID.table_size))
        assert idx.min() >= 0 and idx.max() < GRID.table_size
        if dense:
            assert len(np.unique(idx)) == len(corners) == (res + 1) ** 3
        else:  # the paper's hash, in exact integers
            c = corners.astype(np.uint64)
            h = (c[:, 0] * 1) ^ (c[:, 1] * 2654435761) ^ (c[:, 2] * 805459861)
            assert np.array_equal(idx, (h % GRID.table_size).astype(np.int64))
            assert len(np.unique(idx)) > 0.5 * GRID.table_size  # spread over the table
    rows, weights = enc.lookup(GRID, jnp.asarray(np.random.default_rng(0).random((100, 3)), jnp.float32))
    assert rows.shape == weights.shape == (100, 4, 8)
    assert np.allclose(np.asarray(weights).sum(-1), 1.0, atol=1e-5)
    for level in range(4):  # each level's rows lie in its own slice of the flat table
        r = np.asarray(rows[:, level])
        assert r.min() >= level * GRID.table_size and r.max() < (level + 1) * GRID.table_size


@pytest.mark.slow
def test_encoding_is_continuous_and_its_table_gradient_matches_finite_differences():
    import jax
    import jax.numpy as jnp

    rng = np.random.default_rng(1)
    table = jnp.asarray(rng.uniform(-1, 1, (GRID.levels * GRID.table_size, GRID.features)), jnp.float32)
    x = rng.random((200, 3))
    x[:50, 0] = 5 / 32  # on cell faces of every level
    step = rng.normal(size=(200, 3))
    step /= np.linalg.norm(step, axis=1, keepdims=True)
    f0 = np.asarray(enc.encode(GRID, table, jnp.asarray(x, jnp.float32)))
    lipschitz = float(np.sqrt(3) * 2 * GRID.resolutions().sum())  # per unit length, entries in [-1, 1]
    for h in (1e-3, 1e-4):
        f1 = np.asarray(enc.encode(GRID, table, jnp.asarray(np.clip(x + h * step, 0, 1), jnp.float32)))
        assert np.abs(f1 - f0).max() <= lipschitz * h + 1e-5
    assert np.abs(f1 - f0).max() > 0  # it does move
    with jax.enable_x64(True):
        params = enc.init_field(GRID, 16, jax.random.PRNGKey(0))
        params = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float64), params)
        params["table"] = jnp.asarray(table, jnp.float64) * 0.5
        pts = jnp.asarray(x[:20])

        def total(p):
            sigma, geo = enc.density(GRID, p, pts)
            return jnp.sum(jnp.log1p(sigma)) + jnp.sum(enc.radiance(p, geo) ** 2)

        grad = np.asarray(jax.grad(total)(params)["table"])
        used = np.unique(np.asarray(enc.lookup(GRID, pts)[0]))
        assert np.abs(grad[np.setdiff1d(np.arange(len(grad)), used)]).max() == 0  # untouched entries
        eps = 1e-6
        for row in rng.choice(used, 6, replace=False):
            for col in range(GRID.features):
                plus, minus = dict(params), dict(params)
                plus["table"] = params["table"].at[row, col].add(eps)
                minus["table"] = params["table"].at[row, col].add(-eps)
                fd = (float(total(plus)) - float(total(minus))) / (2 * eps)
                assert fd == pytest.approx(grad[row, col], rel=1e-5, abs=1e-9)


CENTRE, RADIUS, SIGMA = np.array([0.5, 0.45, 0.5]), 0.25, 6.0
"""A sphere of constant density in the unit box."""
EXT = np.ones(3, np.float32)


def _sphere_density(p):
    import jax.numpy as jnp

    return jnp.where(jnp.linalg.norm(p - CENTRE, axis=-1) < RADIUS, SIGMA, 0.0)


def _render_sphere(bits, n: int, offsets):
    """Opacity of rays along +x at distances ``offsets`` from the sphere's centre, and the samples."""
    import functools

    import jax
    import jax.numpy as jnp

    offsets = np.asarray(offsets, np.float32)
    origin = np.stack([np.zeros_like(offsets), CENTRE[1] + offsets, np.full_like(offsets, CENTRE[2])], 1)
    direction = np.tile(np.float32([1, 0, 0]), (len(offsets), 1))
    t0, t1 = np.zeros(len(offsets), np.float32), np.ones(len(offsets), np.float32)
    dt = float(np.linalg.norm(EXT)) / 1024

    @functools.partial(jax.jit, static_argnums=1)
    def run(bits, n):
        points, ray, delta = render.place_samples(bits, EXT, n, origin, direction, t0, t1, jax.random.PRNGKey(0),
                                                  dt, 1024, 8192, 0.25)
        alpha, colour, _ = render.composite(_sphere_density(points), jnp.ones((len(ray), 3)), ray, delta,
                                            len(offsets))
        return alpha, colour, points, ray, delta

    return tuple(np.asarray(a) for a in run(bits, n))


def _sphere_cells(n: int) -> np.ndarray:
    """Flat bits of the cells of an n^3 grid over the unit box that meet the sphere."""
    i = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), -1).reshape(-1, 3)
    nearest = np.clip(CENTRE, i / n, (i + 1) / n)
    return np.linalg.norm(nearest - CENTRE, axis=1) < RADIUS


@pytest.mark.slow
def test_volume_rendering_of_a_constant_density_sphere():
    import jax.numpy as jnp

    offsets = [0.0, 0.1, 0.2, 0.3, -0.3]
    chord = 2 * np.sqrt(np.maximum(RADIUS ** 2 - np.square(offsets), 0))
    expected = 1 - np.exp(-SIGMA * chord)
    n = 32
    full = jnp.ones(n ** 3, bool)
    alpha, colour, _, _, delta_full = _render_sphere(full, n, offsets)
    delta_full = float(delta_full)
    assert np.abs(alpha - expected).max() <= 2 * SIGMA * delta_full  # a sample's worth at either end
    assert alpha[3] == 0 and alpha[4] == 0  # rays that miss
    assert np.allclose(colour[:, 0], alpha, atol=1e-6)  # white samples: colour = opacity
    # only the cells that meet the sphere occupied: the same image from samples packed into them
    bits = jnp.asarray(_sphere_cells(n))
    alpha, _, points, ray, delta = _render_sphere(bits, n, offsets)
    assert np.abs(alpha - expected).max() <= 2 * SIGMA * delta
    used = ray < len(offsets)
    assert np.asarray(bits)[np.asarray(render.cell_index(jnp.asarray(points[used]), EXT, n))].all()
    assert np.all(np.diff(ray) >= 0) and delta < delta_full
    assert set(np.unique(ray[used])) == {0, 1, 2}  # rays through empty cells get no samples


def test_occupancy_grid_marks_the_occupied_cells_and_empties_with_decay():
    import jax
    import jax.numpy as jnp

    n = 16
    values = jnp.zeros(n ** 3)
    threshold = 1.0
    truth = _sphere_cells(n)
    for k in range(8):  # jittered points: the decaying maximum remembers the cells' densities
        points = render.cell_points(EXT, n, jax.random.uniform(jax.random.PRNGKey(k), (n ** 3, 3)))
        values, bits = render.update_occupancy(values, _sphere_density(points), 0.95, threshold)
    bits = np.asarray(bits)
    centres = np.asarray(render.cell_points(EXT, n, jnp.full((n ** 3, 3), 0.5)))
    inside = np.linalg.norm(centres - CENTRE, axis=1) < RADIUS - 0.5 / n * np.sqrt(3)
    assert bits[inside].all() and not bits[~truth].any()
    assert bits.sum() <= truth.sum() and bits.mean() < 0.1
    assert np.array_equal(np.asarray(render.cell_index(jnp.asarray(centres), EXT, n)), np.arange(n ** 3))
    # a region whose density is gone empties once its decayed maximum falls below the threshold
    corner = np.asarray(np.all(centres < 0.2, axis=1))
    both = _sphere_density(jnp.asarray(centres)) + jnp.where(jnp.asarray(corner), SIGMA, 0.0)
    values, bits = render.update_occupancy(jnp.zeros(n ** 3), both, 0.95, threshold)
    assert np.asarray(bits)[corner].all()
    emptied = None
    for k in range(1, 200):
        values, bits = render.update_occupancy(values, _sphere_density(jnp.asarray(centres)), 0.95, threshold)
        bits = np.asarray(bits)
        assert bits[inside].all()
        if emptied is None and not bits[corner].any():
            emptied = k
    limit = min(threshold, float(values.mean()))  # the mean caps the threshold
    assert emptied == int(np.floor(np.log(limit / SIGMA) / np.log(0.95))) + 1
    # the grid's mean caps the threshold: a faint field is still found
    _, bits = render.update_occupancy(jnp.zeros(n ** 3), _sphere_density(jnp.asarray(centres)) * 1e-3, 0.9, 1.0)
    assert np.array_equal(np.asarray(bits), np.linalg.norm(centres - CENTRE, axis=1) < RADIUS)


def test_floaters_and_bubbles_are_dropped():
    import trimesh

    from baselines.common import extract_surface
    from baselines.ngp import drop_floaters

    lo, hi, n = np.zeros(3), np.ones(3), 40
    axes = (np.arange(n) + 0.5) / n
    p = np.stack(np.meshgrid(axes, axes, axes, indexing="ij"), -1)
    big = np.linalg.norm(p - 0.4, axis=-1) < 0.3
    floater = np.linalg.norm(p - 0.85, axis=-1) < 0.06
    bubble = np.linalg.norm(p - 0.4, axis=-1) < 0.06  # a pocket of low density inside
    sigma = np.where((big & ~bubble) | floater, 100.0, 0.0)
    verts, faces = extract_surface(sigma, lo, hi, 50.0, inside_positive=True)
    kept_v, kept_f, dropped = drop_floaters(verts, faces, 0.05)
    mesh = trimesh.Trimesh(kept_v, kept_f)
    assert dropped == 2 and len(mesh.split(only_watertight=False)) == 1 and mesh.is_watertight
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * 0.3 ** 3, rel=0.05)
    assert np.linalg.norm(kept_v - 0.4, axis=1).min() > 0.2  # the bubble's surface went


@pytest.fixture(scope="module")
def tiny3(tmp_path_factory, mitsuba_cpu):
    """cup_1 rendered at 48 px with 3 views (as the diffSDF tests use)."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("ngp") / "cup_1"
    synthesize("cup_1", out, n_views=3, res=48, spp=4, progress=False)
    return out


@pytest.mark.slow
def test_smoke_run_writes_a_mesh_near_the_object(tmp_path, tiny3):
    from baselines.common import input_views
    from ipm.metrics import silhouette_iou
    from ipm.metrics.silhouette import raycast_masks

    assert resolve(METHODS["ngp"].entry) is run_ngp and METHODS["ngp"].layout == "hemi"
    info = run_ngp(tiny3 / "transforms.json", tmp_path / "a", profile="smoke", seed=1, progress=False)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["field.npz", "info.json", "mesh.ply", "timing.json"]
    saved = json.loads((tmp_path / "a" / "info.json").read_text())
    assert saved["views"] == 3 and saved["steps"] == PROFILES["smoke"].steps and saved["colour"]
    assert saved["final_loss"] < 0.5 * saved["first_loss"] and saved["settings"]["level"] == PROFILES["smoke"].level
    assert 0 < saved["occupied_share_final"] < 1  # the grid emptied part of the box
    assert np.allclose(saved["background"], 0.627, atol=0.01)  # the environment's 0.35, sRGB
    mesh = load_mesh(tmp_path / "a" / "mesh.ply")
    assert mesh.is_watertight and np.isfinite(mesh.vertices).all() and len(mesh.faces) > 100
    lo, hi = (np.array(b) for b in info["box"])
    assert (mesh.vertices >= lo - 1e-6).all() and (mesh.vertices <= hi + 1e-6).all()
    views = input_views(tiny3 / "transforms.json", None)
    drawn = raycast_masks(mesh, list(views.c2w), views.width, np.degrees(views.fov_x))
    masks = views.masks > 0.5
    # measured: 0.99 against the input masks, 0.85 against the reference from 8 views of 48 px
    assert ((drawn & masks).sum((1, 2)) / (drawn | masks).sum((1, 2))).min() > 0.95
    assert silhouette_iou(load_mesh(tiny3 / "reference.ply"), mesh, n_views=8, res=48)["iou_mean"] > 0.8
    run_ngp(tiny3 / "transforms.json", tmp_path / "b", profile="smoke", seed=1, progress=False)
    assert np.array_equal(load_mesh(tmp_path / "b" / "mesh.ply").vertices, mesh.vertices)  # seeded
    _field_renders_its_views(tmp_path / "a", tiny3)


def _field_renders_its_views(run, views_path):
    """The saved field rendered again at its input views: deterministic, and nearer the images in
    structure than each one's flat mean colour (measured: SSIM 0.56-0.69 against 0.05-0.11, PSNR
    1-4 dB higher)."""
    from baselines.ngp import render_result
    from ipm.io.views import load_photos, load_views, srgb_bytes
    from ipm.metrics.texture import masked_scores

    views = load_views(views_path / "transforms.json")
    photos, renders = load_photos(views), render_result(run, views)
    assert renders.shape == photos.shape and np.array_equal(renders, render_result(run, views))
    for got, want, mask in zip(renders, photos, views.masks):
        flat = np.broadcast_to(want[mask > 0.5].mean(0), want.shape)
        field = masked_scores(srgb_bytes(got) / 255.0, srgb_bytes(want) / 255.0, mask)
        mean = masked_scores(srgb_bytes(flat) / 255.0, srgb_bytes(want) / 255.0, mask)
        assert field["ssim"] > mean["ssim"] + 0.3 and field["psnr"] > mean["psnr"]


def test_bad_input_is_one_user_error_line(tmp_path, tiny3, capsys):
    from baselines.ngp import render_result
    from ipm.cli import main
    from ipm.io.views import load_views

    with pytest.raises(UserError, match="views"):
        run_ngp(tiny3 / "transforms.json", tmp_path / "x", profile="smoke", n_input_views=1, progress=False)
    with pytest.raises(UserError, match="unknown profile"):
        run_ngp(tiny3 / "transforms.json", tmp_path / "x", profile="fast", progress=False)
    assert set(PROFILES) == {"smoke", "default", "paper"}
    with pytest.raises(UserError, match="no field.npz"):
        render_result(tmp_path, load_views(tiny3 / "transforms.json"))
    code = main(["baseline", "ngp", "--views", str(tiny3 / "transforms.json"), "--out", str(tmp_path / "x"),
                 "--n-input-views", "1", "--threads", "2", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith("ipm baseline: error:")
    assert not (tmp_path / "x").exists()
