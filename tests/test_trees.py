"""Weber-Penn trees: valid, closed, part-labelled meshes; double-sided leaves; seeded stochasticity."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ipm.errors import UserError
from ipm.generators import GENERATORS, get_generator
from ipm.generators.base import Mesh
from ipm.generators.trees import BranchGraph

GEN = get_generator("trees")
PRESETS = sorted(GEN.presets)


def _x(**values) -> np.ndarray:
    return GEN.spec.from_dict(values, GEN.presets["oak"])


def _components(faces: np.ndarray) -> np.ndarray:
    """Connected-component label of each face."""
    adj = trimesh.graph.face_adjacency(faces)
    return trimesh.graph.connected_component_labels(adj, node_count=len(faces))


def _check_part_closed_and_outward(v: np.ndarray, f: np.ndarray) -> None:
    t = trimesh.Trimesh(v, f, process=False)
    assert t.is_watertight and t.is_winding_consistent  # every edge in exactly two faces
    comp = _components(f)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    signed = np.bincount(comp, np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0)
    assert np.all(signed > 0)  # every tube / leaf winds outward (one-sided area emitters)


def _check_leaves_double_sided(v: np.ndarray, f: np.ndarray, n_check: int = 60) -> None:
    """Each leaf is flat and shows outward faces to both sides of its plane, covering its outline."""
    comp = _components(f)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]) / 2.0  # area vectors
    for leaf in range(min(n_check, comp.max() + 1)):
        sel = comp == leaf
        pts = v[np.unique(f[sel])]
        centred = pts - pts.mean(0)
        _, s, vt = np.linalg.svd(centred, full_matrices=False)
        normal = vt[2]
        assert s[2] < 0.2 * s[1]  # a thin leaf, not a blob
        proj = fn[sel] @ normal
        up, down = proj[proj > 0].sum(), -proj[proj < 0].sum()
        assert up > 0 and down > 0
        assert up == pytest.approx(down, rel=1e-6)  # each side alone covers the whole outline


def _check_mesh(m: Mesh, height: float, leaves: bool) -> None:
    v, f = m.vertices, m.faces
    assert isinstance(m, Mesh) and m.part_names == ("branch", "foliage")
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(m.normals)) and np.all(np.isfinite(m.uv))
    assert f.min() >= 0 and f.max() < len(v)
    assert len(m.labels) == len(f) and m.uv.shape == (len(f), 3, 2) and len(m.normals) == len(v)
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-6)
    assert set(np.unique(m.labels)) == ({0, 1} if leaves else {0})
    assert abs(v[:, 1].min()) < 1e-9  # stands on y = 0
    assert 0.3 <= np.ptp(v[:, 1]) <= 2.5
    assert np.ptp(v[:, 1]) == pytest.approx(height)
    _check_part_closed_and_outward(v, f[m.labels == 0])


@pytest.mark.parametrize("name", PRESETS)
def test_presets_are_valid_closed_trees(name):
    x = GEN.presets[name]
    assert np.all(x >= GEN.spec.lower) and np.all(x <= GEN.spec.upper)
    m, graph = GEN.generate(x, 0)
    _check_mesh(m, x[GEN.spec.index["height"]], leaves=True)
    _check_part_closed_and_outward(m.vertices, m.faces[m.labels == 1])
    _check_leaves_double_sided(m.vertices, m.faces[m.labels == 1])
    assert graph.n_leaves > 100 and graph.n_vertices > 100


def test_random_parameters_give_valid_trees(rng):
    for _ in range(6):
        x = GEN.spec.from_unit(rng.random(len(GEN.spec)))
        m, graph = GEN.generate(x, 0)
        _check_mesh(m, x[GEN.spec.index["height"]], leaves=graph.n_leaves > 0)
        if graph.n_leaves:
            _check_leaves_double_sided(m.vertices, m.faces[m.labels == 1], n_check=20)


def test_presets_look_different():
    """Crown proportions (width / height) and leaf counts set the species apart."""
    stats = {}
    for name in PRESETS:
        v = GEN.mesh(GEN.presets[name], 0).vertices
        stats[name] = np.ptp(v[:, [0, 2]], axis=0).mean() / np.ptp(v[:, 1])
    assert stats["poplar"] < 0.35 < stats["pine"]  # tall and narrow vs a broad cone
    assert stats["bush"] > stats["pine"]
    assert len({round(s, 2) for s in stats.values()}) == len(PRESETS)


def test_branch_graph_is_a_tree_rooted_at_the_base():
    x = GEN.presets["oak"]
    m, g = GEN.generate(x, 0)
    assert isinstance(g, BranchGraph)
    n = g.n_vertices
    assert g.edges.shape == (n - 1, 2) and g.positions.shape == (n, 3) and g.radii.shape == (n,)
    assert np.all(g.radii > 0)
    # every node but the root has exactly one parent, and following parents reaches node 0
    parent = np.full(n, -1)
    parent[g.edges[:, 1]] = g.edges[:, 0]
    assert np.sum(parent < 0) == 1 and parent[0] == -1
    node = np.arange(n)
    for _ in range(n):
        live = node > 0
        if not live.any():
            break
        node[live] = parent[node[live]]
    assert np.all(node == 0)
    np.testing.assert_allclose(g.positions[0], 0.0, atol=1e-9)  # trunk base at the origin
    lo, hi = m.vertices.min(0), m.vertices.max(0)
    assert np.all(g.positions >= lo - 1e-9) and np.all(g.positions <= hi + 1e-9)
    assert set(np.unique(g.levels)) == {0, 1, 2, 3}


def test_same_parameters_give_identical_meshes():
    x = GEN.presets["bush"]
    (a, ga), (b, gb) = GEN.generate(x, 1), GEN.generate(x.copy(), 1)
    for field in ("vertices", "faces", "normals", "uv", "labels"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert np.array_equal(ga.positions, gb.positions) and np.array_equal(ga.edges, gb.edges)


def test_seed_changes_the_tree_but_not_its_size():
    a = GEN.mesh(_x(seed=1), 0)
    b = GEN.mesh(_x(seed=2), 0)
    assert a.vertices.shape != b.vertices.shape or not np.allclose(a.vertices, b.vertices)
    assert np.ptp(a.vertices[:, 1]) == pytest.approx(np.ptp(b.vertices[:, 1]))


def test_deeper_levels_keep_the_upper_levels_in_place():
    """Per-level random streams: level-3 parameters move neither the trunk nor levels 1 and 2."""

    def upper(x):
        g = GEN.branch_graph(x)
        rel = (g.positions - g.positions[0]) / np.linalg.norm(g.positions[1] - g.positions[0])
        return rel[g.levels <= 2]

    base = upper(_x())
    np.testing.assert_allclose(upper(_x(l3_length=0.2, l3_branches=9, l3_curve=50.0)), base, atol=1e-9)
    assert upper(_x(l2_down_angle=20.0)).shape != base.shape or not np.allclose(upper(_x(l2_down_angle=20.0)), base)


def test_levels_add_branch_graph_nodes():
    counts = [GEN.branch_graph(_x(levels=n)).n_vertices for n in (1, 2, 3)]
    assert counts[0] < counts[1] < counts[2]
    for n in (1, 2, 3):  # leaves move to the deepest level
        assert set(np.unique(GEN.mesh(_x(levels=n), 0).labels)) == {0, 1}


def test_no_leaves_gives_branches_only():
    m, g = GEN.generate(_x(leaves=0), 0)
    assert set(np.unique(m.labels)) == {0} and g.n_leaves == 0


@pytest.mark.parametrize("name", PRESETS)
def test_level_of_detail_adds_vertices_not_branches(name):
    x = GEN.presets[name]
    out = [GEN.generate(x, lod) for lod in GEN.lods]
    verts = [len(m.vertices) for m, _ in out]
    assert verts == sorted(set(verts))  # strictly increasing
    assert len({g.n_vertices for _, g in out}) == 1 and len({g.n_leaves for _, g in out}) == 1


def test_registered_and_usable_like_ground_truth():
    from ipm.synth import ground_truth_mesh

    assert "trees" in GENERATORS and GEN.differentiable is False
    m = get_generator("trees").mesh(GEN.presets["pine"], 0)
    assert isinstance(m, Mesh)
    case = {"source": {"generator": "trees", "preset": "pine", "params": {"seed": 3}},
            "pose": {"yaw_deg": 30.0, "scale": 0.5}}
    v, f, labels, uv = ground_truth_mesh(case, lod=0)
    assert v.shape[1] == 3 and len(labels) == len(f) and uv.shape == (len(f), 3, 2) and set(np.unique(labels)) == {0, 1}
    assert np.ptp(v[:, 1]) == pytest.approx(0.5 * GEN.presets["pine"][GEN.spec.index["height"]])
    with pytest.raises(NotImplementedError, match="not differentiable"):
        GEN.positions_fn((), 0)


def test_bad_names_and_values_raise_user_errors():
    with pytest.raises(UserError, match="unknown parameter"):
        GEN.spec.from_dict({"l4_branches": 3})
    with pytest.raises(UserError, match="unknown trees preset"):
        GEN.preset("baobab")
    assert np.array_equal(GEN.preset("oak"), GEN.presets["oak"])
    with pytest.raises(UserError, match="finite"):
        GEN.mesh(np.full(len(GEN.spec), np.nan), 0)
    with pytest.raises(UserError, match="level of detail"):
        GEN.mesh(GEN.presets["oak"], 7)


def test_spec_is_moderate_and_flags_integers():
    spec = GEN.spec
    assert 30 <= len(spec) <= 60
    integers = {"shape", "levels", "seed", "base_splits", "trunk_curve_res", "leaves", "leaf_shape"}
    integers |= {f"l{n}_{k}" for n in (1, 2, 3) for k in ("branches", "curve_res")}
    assert {n for n, d in zip(spec.names, spec.discrete) if d} == integers
    assert np.all(spec.default >= spec.lower) and np.all(spec.default <= spec.upper)
    assert set(PRESETS) == {"oak", "pine", "poplar", "bush"}
