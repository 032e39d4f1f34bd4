"""The JAX silhouette renderer (``ipm.render.edges``): coverage against Mitsuba and an independent
ray caster, edge-sampling gradients against central differences and against Mitsuba's, batching,
the span budget, a class mask (a building's windows) against Mitsuba's and its gradient against
central differences, and its refusals."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.metrics import raycast_masks
from ipm.problem import Problem
from ipm.render.cameras import orbit_camera
from ipm.render.edges import EdgeRenderer
from ipm.render.silhouette import SilhouetteRenderer
from tests.conftest import as_the_package, slow_except

FOV = 0.7
POSE = ("yaw", "tilt_x", "tilt_z", "dx", "dy", "dz", "log_scale")


def _cams():
    return np.stack([orbit_camera([0, 0.5, 0], 3.0, 20, 25), orbit_camera([0, 0.5, 0], 3.0, 110, 5)])


def _mug(lod=0):
    gen = get_generator("dishes")
    problem = Problem(gen, np.zeros(3), 1.0)
    z0 = problem.initial_z(gen.spec.to_unit(gen.presets["mug"]), 0.3)
    key = problem.key(z0)
    topo = gen.topology(key, lod)
    return gen, problem, z0, problem.vertex_fn(key, lod), topo


@pytest.mark.slow
def test_coverage_matches_ray_cast_and_mitsuba(mitsuba_cpu):
    """Pixels more than half covered agree with open3d's ray caster and with Mitsuba's render (IoU
    > 0.97, the rest edge pixels), and the covered area matches Mitsuba's within 1 %."""
    gen = get_generator("dishes")
    m = gen.mesh(gen.presets["mug"], 1)
    cams = _cams()
    ours = EdgeRenderer(cams, FOV, 96, 96, spp=16).render(m.vertices, m.faces)
    theirs = SilhouetteRenderer(cams, FOV, 96, 96, spp=16).render(m.vertices, m.faces)
    rc = raycast_masks(trimesh.Trimesh(m.vertices, m.faces, process=False), list(cams), res=96,
                       fov_deg=np.degrees(FOV))
    for a, b, c in zip(ours, theirs, rc):
        for other in (b > 0.5, c):
            assert ((a > 0.5) & other).sum() / ((a > 0.5) | other).sum() > 0.97
        assert a.sum() == pytest.approx(b.sum(), rel=0.01)
        assert np.abs(a - b).max() < 0.8  # no pixel inside one and outside the other


def test_coverage_is_unbiased_area():
    """One triangle: the mean coverage over render seeds is its exact area in pixels."""
    c2w = orbit_camera([0, 0, 0], 2.0, 0, 0)[None]
    tri = np.array([[-0.3, -0.2, 0.0], [0.35, -0.25, 0.0], [0.05, 0.4, 0.0]])
    r = EdgeRenderer(c2w, FOV, 48, 48, spp=4)
    area = np.mean([r.render(tri, np.array([[0, 1, 2]]), seed=s).sum() for s in range(40)])
    f = 0.5 * 48 / np.tan(0.5 * FOV)
    p = tri[:, :2] * f / 2.0  # the triangle faces the camera at distance 2
    (ax, ay), (bx, by) = p[1] - p[0], p[2] - p[0]
    exact = 0.5 * abs(ax * by - ay * bx)
    assert area == pytest.approx(exact, rel=0.01)


@pytest.mark.parametrize("name, shift, delta", slow_except([
    ("profile_4", 0.1, 0.005), ("y_scale", 0.1, 0.005), ("handle_radius_10", 0.3, 0.02),
    ("yaw", 0.3, 0.005), ("dx", 0.05, 0.005), ("log_scale", 0.05, 0.005),
], "profile_4"))
@pytest.mark.slow
def test_gradient_matches_central_differences(name, shift, delta):
    """d loss / d z by edge sampling (mean over 8 render seeds) against central differences of the
    loss of high-sample renders (64 per pixel, the same sample grid on both sides)."""
    gen, problem, z0, fn, topo = _mug()
    i = gen.spec.index[name] if name in gen.spec.index else problem.n_shape + POSE.index(name)
    cams = _cams()
    fine = EdgeRenderer(cams, FOV, 64, 64, spp=64)

    def render(z, seed):
        return fine.render(np.asarray(fn(z)).reshape(-1, 3), topo.faces, seed=seed)

    zt = z0.copy()
    zt[i] += shift
    targets = render(zt, seed=7)
    renderer = EdgeRenderer(cams, FOV, 64, 64, spp=16)
    grad = np.mean([renderer.loss_and_grad(fn, z0, topo.faces, topo.n_vertices, targets, seed=s)[1][i] for s in range(8)])
    zp, zm = z0.copy(), z0.copy()
    zp[i] += delta
    zm[i] -= delta
    fd = np.mean([(np.mean((render(zp, s) - targets) ** 2) - np.mean((render(zm, s) - targets) ** 2)) / (2 * delta)
                  for s in (3, 4)])
    assert fd < 0  # moving towards the target lowers the loss
    assert grad == pytest.approx(fd, rel=0.15)


@pytest.mark.slow
def test_gradient_matches_mitsuba(mitsuba_cpu):
    """The whole gradient vector (shape and pose) points where Mitsuba's does: cosine > 0.97
    between the means over 6 render seeds each, and the norms agree within 10 %."""
    gen, problem, z0, fn, topo = _mug()
    cams = _cams()
    zt = z0.copy()
    zt[: problem.n_shape] = np.clip(zt[: problem.n_shape] + 0.05, 0, 1)
    zt[problem.n_shape + POSE.index("log_scale")] += 0.05
    targets = SilhouetteRenderer(cams, FOV, 64, 64, spp=64).render(np.asarray(fn(zt)).reshape(-1, 3), topo.faces)
    ours = EdgeRenderer(cams, FOV, 64, 64, spp=16)
    theirs = SilhouetteRenderer(cams, FOV, 64, 64, spp=16)
    g = [np.mean([r.loss_and_grad(fn, z0, topo.faces, topo.n_vertices, targets, seed=s)[1] for s in range(6)], 0)
         for r in (ours, theirs)]
    assert g[0] @ g[1] / np.linalg.norm(g[0]) / np.linalg.norm(g[1]) > 0.97
    assert np.linalg.norm(g[0]) == pytest.approx(np.linalg.norm(g[1]), rel=0.1)


@pytest.mark.slow
def test_a_span_budget_far_too_small_is_grown():
    """A renderer starting from a span budget far too small grows it until the image is complete:
    its losses and gradients are those of a renderer whose first budget sufficed."""
    gen, problem, z0, fn, topo = _mug()
    cams = _cams()[:1]
    targets = EdgeRenderer(cams, FOV, 48, 48).render(np.asarray(fn(z0)).reshape(-1, 3), topo.faces)
    zs = z0 + np.random.default_rng(0).normal(0, 0.02, (3, len(z0)))
    r = EdgeRenderer(cams, FOV, 48, 48)
    for z, s in zip(zs, (5, 6, 7)):
        loss, grad = r.loss_and_grad(fn, z, topo.faces, topo.n_vertices, targets, seed=s)
        small = EdgeRenderer(cams, FOV, 48, 48, spans=64)
        single = small.loss_and_grad(fn, z, topo.faces, topo.n_vertices, targets, seed=s)
        assert single[0] == pytest.approx(loss, rel=1e-4)
        np.testing.assert_allclose(single[1], grad, rtol=1e-3, atol=1e-6)


@pytest.mark.slow
def test_target_masks_kept_on_the_device_follow_the_array_passed():
    """The renderer keeps target masks on the device per array object: switching between two
    targets, and passing a fresh array each call, gives the losses of a renderer that never saw
    them before."""
    gen, problem, z0, fn, topo = _mug()
    cams = _cams()[:1]
    full = EdgeRenderer(cams, FOV, 32, 32).render(np.asarray(fn(z0)).reshape(-1, 3), topo.faces)
    empty = np.zeros_like(full)

    def fresh(targets):
        return EdgeRenderer(cams, FOV, 32, 32).loss_and_grad(fn, z0, topo.faces, topo.n_vertices, targets, seed=1)[0]

    r = EdgeRenderer(cams, FOV, 32, 32)
    for targets in (full, empty, full, empty.copy(), full.copy(), *[np.zeros_like(full) for _ in range(5)], full):
        assert r.loss_and_grad(fn, z0, topo.faces, topo.n_vertices, targets, seed=1)[0] == fresh(targets)
    assert fresh(empty) > 10 * fresh(full)


def test_refusals():
    """More than two class masks are refused with one line."""
    gen, problem, z0, fn, topo = _mug()
    r = EdgeRenderer(_cams()[:1], FOV, 32, 32)
    with pytest.raises(UserError, match="at most 2 class masks"):
        r.loss_and_grad(fn, z0, [topo.faces, topo.faces[:2], topo.faces[2:4], topo.faces[4:6]], topo.n_vertices,
                        np.zeros((1, 32, 32)))


def _house(classes=("window",)):
    """The house preset at level 2 split into the faces of each of ``classes`` and the rest (first),
    and two cameras."""
    from ipm.io.semantic import BUILDING_LABELS

    gen = get_generator("buildings")
    problem = Problem(gen, np.zeros(3), 1.0)
    z0 = problem.initial_z(gen.spec.to_unit(gen.presets["house"]), 0.4)
    key = problem.key(z0)
    topo, fn = gen.topology(key, 2), problem.vertex_fn(key, 2)
    label = np.asarray(gen.part_semantic)[topo.labels]
    inside = [label == BUILDING_LABELS[c] for c in classes]
    cams = np.stack([orbit_camera([0, 0.5, 0], 2.6, 15, 15), orbit_camera([0, 0.5, 0], 2.6, 100, 30)])
    return gen, z0, fn, topo, [topo.faces[~np.any(inside, 0)]] + [topo.faces[m] for m in inside], cams


@pytest.mark.parametrize("classes", slow_except([("window",), ("window", "roof")], "window"))
@pytest.mark.slow
def test_class_mask_matches_mitsuba(mitsuba_cpu, classes):
    """A building's silhouette and its visible window mask (recessed panes, partly hidden by their
    reveals at an angle), and its roof's, agree with Mitsuba's: pixels more than half covered at
    IoU > 0.95, the covered areas within 1 %, no pixel inside one and outside the other."""
    gen, z0, fn, topo, groups, cams = _house(classes)
    v = np.asarray(fn(z0)).reshape(-1, 3)
    ours = EdgeRenderer(cams, FOV, 96, 96, spp=16).render(v, groups)
    theirs = SilhouetteRenderer(cams, FOV, 96, 96, spp=64).render(v, groups)
    assert ours.shape == theirs.shape == (2, 1 + len(classes), 96, 96)
    for a, b in zip(ours.reshape(-1, 96, 96), theirs.reshape(-1, 96, 96)):
        assert ((a > 0.5) & (b > 0.5)).sum() / ((a > 0.5) | (b > 0.5)).sum() > 0.95
        assert a.sum() == pytest.approx(b.sum(), rel=0.01)
        assert np.abs(a - b).max() < 0.5
    assert 50 < ours[:, 1].sum(axis=(1, 2)).min() < 0.2 * ours[:, 0].sum()  # windows seen in both views
    if len(classes) == 2:  # the roof: a large share of the house, apart from the windows
        assert 0.15 * ours[:, 0].sum() < ours[:, 2].sum() < 0.6 * ours[:, 0].sum()
        assert (np.minimum(ours[:, 1], ours[:, 2]) > 0.5).sum() == 0


@pytest.mark.slow
@pytest.mark.parametrize("name,classes", [("window_width", ("window",)), ("window_sill", ("window",)),
                                          ("roof_overhang", ("window", "roof"))])
def test_class_gradient_matches_central_differences(mitsuba_cpu, name, classes):
    """The class terms' gradient by edge sampling (mean over 6 render seeds) against central
    differences of the loss of Mitsuba's 64-sample renders (an independent renderer): within 15 %
    (windows: measured 0.94 x and 0.99 x; Mitsuba's own gradient gives 0.62 x and 0.40 x,
    tests/test_windows.py); with the roof's mask as a second class, the roof's overhang (0.99 x)."""
    gen, z0, fn, topo, groups, cams = _house(classes)
    cams, i = cams[:1], gen.spec.index[name]
    fine = SilhouetteRenderer(cams, FOV, 96, 96, spp=64)

    def render(z, seed):
        return fine.render(np.asarray(fn(z)).reshape(-1, 3), groups, seed=seed)

    zt = z0.copy()
    zt[i] += 0.2
    target = render(zt, seed=7)

    def loss(z, seed):
        img = render(z, seed)
        return sum(np.mean((img[:, k] - target[:, k]) ** 2) for k in range(len(groups)))

    ours = EdgeRenderer(cams, FOV, 96, 96, spp=16)
    grad = np.mean([ours.loss_and_grad(fn, z0, groups, topo.n_vertices, target[:, 0], seed=s,
                                       highlight_targets=target[:, 1:], highlight_weight=[1.0] * len(classes))[1][i]
                    for s in range(6)])
    zp, zm = z0.copy(), z0.copy()
    zp[i] += 0.01
    zm[i] -= 0.01
    fd = np.mean([(loss(zp, s) - loss(zm, s)) / 0.02 for s in (3, 4)])
    assert fd < 0  # moving towards the target's windows lowers the loss
    assert grad == pytest.approx(fd, rel=0.15)


@pytest.mark.slow
def test_back_faces_culled_on_closed_solids_change_nothing_but_the_work():
    """A building (closed, outward-facing solids) drawn with back faces culled: the same silhouette
    and window masks, the same loss and the same gradient in every vertex (same seed) as with every
    face drawn, from fewer spans and fragments; with the programs compiled as the package compiles
    them (not the tests' ``TEST_COMPILE``: drawn with its back faces, a closed solid's coincident
    front and back edges meet in ties that the rounding of unoptimized programs settles otherwise,
    2 % of the gradient, where the culled drawing does not move). The gradient is the vertices',
    which the generator's pullback (checked on its own) carries to its parameters: equal here,
    equal there, without compiling a building's pullback."""
    as_the_package("tests.test_render_edges:culling_changes_nothing_but_the_work", quick_compile=True)


def _vertices_as_given(v):
    """The flattened vertices themselves: a loss's gradient in each vertex."""
    return v


def culling_changes_nothing_but_the_work():
    """The check of :func:`test_back_faces_culled_on_closed_solids_change_nothing_but_the_work`."""
    gen, z0, fn, topo, groups, cams = _house(("window",))
    v = np.asarray(fn(z0)).reshape(-1, 3)
    plain, culled = (EdgeRenderer(cams, FOV, 64, 64, spp=4, cull_back=c) for c in (False, True))
    masks = plain.render(v, groups, seed=2)
    np.testing.assert_allclose(culled.render(v, groups, seed=2), masks, atol=1e-6)
    z1 = z0.copy()
    z1[gen.spec.index["window_width"]] += 0.15
    args = (_vertices_as_given, np.asarray(fn(z1), np.float32), groups, topo.n_vertices, masks[:, 0])
    kw = dict(seed=5, highlight_targets=masks[:, 1], highlight_weight=1.0)
    (la, ga), (lb, gb) = plain.loss_and_grad(*args, **kw), culled.loss_and_grad(*args, **kw)
    assert lb == pytest.approx(la, rel=1e-6) and np.abs(ga).max() > 0
    np.testing.assert_allclose(gb, ga, rtol=1e-4, atol=1e-6 * np.abs(ga).max())
    from ipm.render.edge_programs import _face_classes

    faces, classes = _face_classes(groups)
    assert np.all(np.less(culled.needed(v, faces, classes), plain.needed(v, faces, classes)))


@pytest.mark.slow
def test_meshes_of_one_padded_size_differing_inside_are_told_apart():
    """Face arrays padded to one size with the same first and last triangles, drawn in turn by one
    renderer, each give their own image (the faces kept on the device are looked up by content)."""
    c2w = orbit_camera([0, 0, 0], 2.0, 0, 0)[None]
    quad = np.array([[-0.4, -0.4, 0.0], [0.4, -0.4, 0.0], [0.4, 0.4, 0.0], [-0.4, 0.4, 0.0], [0.0, 0.0, 0.0]])
    filler = np.tile([[0, 1, 4]], (20, 1))  # the same ends in both
    one, two = ([filler, np.array([[k, k + 1, 4]] * 5), filler] for k in (1, 2))
    meshes = [[np.concatenate(m), np.zeros((0, 3), int)] for m in (one, two)]
    shared = EdgeRenderer(c2w, FOV, 32, 32)
    for faces in meshes + meshes[::-1]:
        alone = EdgeRenderer(c2w, FOV, 32, 32).render(quad, faces)
        np.testing.assert_allclose(shared.render(quad, faces), alone)
    assert not np.allclose(*(EdgeRenderer(c2w, FOV, 32, 32).render(quad, m) for m in meshes))


@pytest.mark.slow
def test_back_faces_culled_only_where_asked():
    """With ``cull_back`` a triangle seen from behind is not drawn, one seen from its front is; without,
    both are."""
    c2w = orbit_camera([0, 0, 0], 2.0, 0, 0)[None]
    tri = np.array([[-0.3, -0.2, 0.0], [0.35, -0.25, 0.0], [0.05, 0.4, 0.0]])  # counter-clockwise, seen from +z
    for cull in (True, False):
        for faces, front in (([[0, 1, 2]], True), ([[0, 2, 1]], False)):
            out = EdgeRenderer(c2w, FOV, 32, 32, cull_back=cull).render(tri, [np.array(faces), np.zeros((0, 3), int)])
            assert (out[0, 0].sum() > 20) == (front or not cull)


def test_vertices_behind_the_camera_are_dropped():
    """A triangle reaching behind the camera plane is not drawn (no wrap-around smears)."""
    c2w = orbit_camera([0, 0, 0], 2.0, 0, 0)[None]
    tri = np.array([[-0.3, -0.2, 0.0], [0.35, -0.25, 0.0], [0.05, 0.4, 3.0]])  # third vertex behind the eye
    assert EdgeRenderer(c2w, FOV, 32, 32).render(tri, np.array([[0, 1, 2]])).sum() == 0


def test_span_budget_headroom_by_backend(monkeypatch):
    """A third more spans than needed on a CPU (a quarter when grown: work grows with the budget);
    three times on a GPU, where each new budget is a long compilation and a bigger one costs little."""
    import jax

    from ipm.render import edges

    assert edges.with_headroom(300, grown=False) == 400 and edges.with_headroom(300, grown=True) == 375
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert edges.with_headroom(300, grown=False) == edges.with_headroom(300, grown=True) == 900


@pytest.fixture
def fresh_programs():
    """The renderer's program builders emptied before and after (their programs hold how they were built)."""
    from ipm.render import edges

    builders = (edges._render_fn, edges._class_render_fn, edges._loss_fn, edges._silhouette_loss, edges._class_loss_fn,
                edges._pullback)

    def clear():
        for b in builders:
            b.cache_clear()

    clear()
    yield clear
    clear()


@pytest.mark.slow
def test_programs_kept_between_processes_give_the_same_numbers(monkeypatch, tmp_path, fresh_programs):
    """With a program folder the renderer's programs (silhouette loss, render, class-mask loss) and
    those around a generator's named vertex program (the mug's loss, its pullback) are exported
    there and give the numbers of programs traced afresh; a later process loads them without
    tracing (export made to fail); a file that does not read back is exported again."""
    from jax import export

    from ipm.render import edges, programs
    from ipm.render.edge_programs import split

    gen, problem, z0, fn, topo = _mug()
    _, hz, hfn, htopo, groups, hcams = _house()
    cams = _cams()[:1]
    targets = EdgeRenderer(cams, FOV, 32, 32).render(np.asarray(fn(z0)).reshape(-1, 3), topo.faces)
    z = z0 + np.random.default_rng(0).normal(0, 0.02, len(z0))
    v = np.asarray(hfn(hz)).reshape(-1, 3)
    faces, classes = edges._face_classes(groups)
    h = EdgeRenderer(hcams[:1], FOV, 32, 32)
    blank = np.zeros((1, 32, 32), np.float32)
    budgets = h._budget("house", lambda: v, faces, classes)

    def numbers(every: bool = True):
        r = EdgeRenderer(cams, FOV, 32, 32)
        out = list(r.loss_and_grad(fn, z, topo.faces, topo.n_vertices, targets, seed=3))
        program, constants, name = split(fn)
        out.append(edges._pullback(program, name)(z, constants, np.linspace(-1, 1, 3 * topo.n_vertices)))
        if every:  # the class loss without the building's pullback (half a minute to compile)
            class_loss = edges._class_loss_fn(32, 32, h.ss, budgets, ((0.5,), 1, "mse"))
            out += [*h.render(v, groups)[0],
                    *class_loss(v.reshape(-1), faces, classes, blank, blank[:, None], h._w2c, h.focal,
                                h._jitter(1))[:2]]
        return out

    monkeypatch.setattr(programs, "program_folder", lambda: None)  # every program traced here
    traced = numbers()
    folder = tmp_path / "programs"
    monkeypatch.setattr(programs, "program_folder", lambda: folder)
    fresh_programs()
    for a, b in zip(traced, numbers()):
        np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-9)
    # the mug's loss, the silhouette loss it calls, the mug's pullback, class loss, class render
    assert len(list(folder.glob("*.jaxexport"))) == 5

    def no_export(*args, **kwargs):
        raise AssertionError("traced again")

    half = b"half a program"
    for stored in folder.glob("*.jaxexport"):
        stored.write_bytes(half)
    fresh_programs()
    numbers(every=False)  # the unreadable files it reads exported again
    assert sum(p.read_bytes() != half for p in folder.glob("*.jaxexport")) == 3
    with monkeypatch.context() as m:
        m.setattr(export, "export", no_export)
        fresh_programs()
        for a, b in zip(traced, numbers(every=False)):
            np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-9)
    assert len(list(folder.glob("*.jaxexport"))) == 5


def test_program_folder_keeps_the_most_recently_used(tmp_path):
    """Beyond ``keep`` stored programs the least recently used (oldest modification time: a load
    touches its file) are removed; other files in the folder are left alone."""
    import os

    from ipm.render import programs

    for i in range(5):
        p = tmp_path / f"{i}.jaxexport"
        p.write_bytes(b"x")
        os.utime(p, (1000 + i, 1000 + [3, 0, 4, 1, 2][i]))
    (tmp_path / "note.txt").write_text("kept")
    programs._prune(tmp_path, keep=3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0.jaxexport", "2.jaxexport", "4.jaxexport", "note.txt"]
    programs._prune(tmp_path, keep=3)
    assert len(list(tmp_path.glob("*.jaxexport"))) == 3


def test_kernels_written_out_equal_their_reductions():
    """The pixel areas (sums of strided slices) equal the mean over a reshape to the bit, and a
    ray's depth (its dot product written out) equals the reduction's to rounding."""
    import jax.numpy as jnp

    from ipm.render.edge_classes import ray_depth
    from ipm.render.edge_scan import pixel_area

    rng = np.random.default_rng(0)
    for ss in (1, 2, 3):
        covered = rng.random((12 * ss, 10 * ss)) > 0.4
        mean = covered.reshape(12, ss, 10, ss).mean((1, 3))
        assert np.array_equal(np.asarray(pixel_area(jnp.asarray(covered), ss)), mean.astype(np.float32))
    n, k = rng.normal(size=(50, 3)).astype(np.float32), rng.normal(size=50).astype(np.float32)
    face = rng.integers(0, 50, 200)
    x, y = (rng.random(200) * 64).astype(np.float32), (rng.random(200) * 48).astype(np.float32)
    depth = np.asarray(ray_depth((jnp.asarray(n), jnp.asarray(k)), jnp.asarray(face), jnp.asarray(x), jnp.asarray(y),
                                 50.0, 64, 48))
    d = np.stack([(x - 32) / 50.0, -(y - 24) / 50.0, -np.ones_like(x)], -1).astype(np.float64)
    t = k[face] / np.sum(n[face] * d, -1)
    want = np.where(t > 0, t, np.inf)
    assert np.isfinite(depth).sum() == np.isfinite(want).sum() > 50
    np.testing.assert_allclose(depth[np.isfinite(want)], want[np.isfinite(want)], rtol=1e-4)
