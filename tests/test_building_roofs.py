"""The buildings generator's roofs and wings: nine roof kinds as closed solids with planar faces,
the ridge's inset sliding a half-hip from a gable to a hip, wings that the plan and the annex
switch on, and roofs of one pitch meeting where wings join as a straight skeleton's do (checked
against an independent straight-skeleton library)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ipm.generators import get_generator
from ipm.generators.buildings.table import (FLAT, GABLE, HALF_HIP, HIP, L_PLAN, PLANS, RECTANGLE, ROOF, ROOF_KINDS,
                                            T_PLAN, U_PLAN, WALLS, WINDOWS)


@pytest.fixture(scope="module")
def gen():
    return get_generator("buildings")


def _house(gen, **values) -> np.ndarray:
    base = {"chimney": 0, "roof_overhang": 0.0, "width": 1.6, "depth": 1.0, "floors": 2, "floor_height": 0.3,
            "ground_extra": 0.0, "roof_height": 0.4}
    return gen.spec.from_dict(base | values, gen.presets["house"])


def _roof_mesh(gen, x) -> trimesh.Trimesh:
    m = gen.mesh(x, 0)
    return trimesh.Trimesh(m.vertices, m.faces[m.labels == ROOF], process=True)


def _plane_groups(mesh: trimesh.Trimesh) -> int:
    """Faces whose corners all lie on the plane of a face of another orientation would merge:
    the number of distinct (normal, offset) planes among the non-degenerate faces."""
    keep = mesh.area_faces > 1e-9
    n = mesh.face_normals[keep]
    d = np.einsum("ij,ij->i", n, mesh.triangles_center[keep])
    return len(np.unique(np.round(np.c_[n, d], 5), axis=0))


@pytest.mark.parametrize("kind", range(1, len(ROOF_KINDS)), ids=ROOF_KINDS[1:])
def test_every_pitched_kind_is_a_closed_solid_of_planar_faces(gen, kind):
    roof = _roof_mesh(gen, _house(gen, roof_type=kind))
    assert roof.is_watertight and roof.is_winding_consistent and roof.volume > 0
    # every face planar: no two faces of a plane-group bend, so the planes are few (a box's 6 and a
    # mansard's 9 at most: bottom, four lower slopes, two upper slopes, two upper hips)
    assert _plane_groups(roof) <= 9
    # the roof stands on the walls' top and rises to the roof height, not above it
    assert roof.bounds[0, 1] == pytest.approx(0.6, abs=1e-5) and roof.bounds[1, 1] == pytest.approx(1.0, abs=1e-5)


def test_roof_kinds_differ_and_keep_their_volume_rules(gen):
    volume = {kind: _roof_mesh(gen, _house(gen, roof_type=kind)).volume for kind in range(1, len(ROOF_KINDS))}
    prism = 0.5 * 1.6 * 1.0 * 0.4  # a gable: half the box under it
    assert volume[GABLE] == pytest.approx(prism, rel=1e-4)
    # moving the ridge (saltbox) or putting it over the back eave (skillion) keeps the prism's volume
    assert volume[ROOF_KINDS.index("saltbox")] == pytest.approx(prism, rel=1e-4)
    assert volume[ROOF_KINDS.index("skillion")] == pytest.approx(prism, rel=1e-4)
    # hips cut the gable's ends; a gambrel's bent slopes hold more
    assert volume[HIP] < prism and volume[ROOF_KINDS.index("pyramidal")] < volume[HIP]
    assert volume[ROOF_KINDS.index("gambrel")] > prism


def test_the_ridge_inset_slides_a_half_hip_from_gable_to_hip(gen):
    def volume(kind, inset):
        return _roof_mesh(gen, _house(gen, roof_type=kind, hip_ratio=inset)).volume

    assert volume(HALF_HIP, 0.0) == pytest.approx(volume(GABLE, 0.3), rel=1e-5)
    assert volume(HALF_HIP, 1.0) == pytest.approx(volume(HIP, 1.0), rel=1e-5)
    steps = [volume(HALF_HIP, t) for t in np.linspace(0.0, 1.0, 6)]
    assert all(a > b for a, b in zip(steps, steps[1:]))


@pytest.mark.parametrize("plan,annex,wings", [(RECTANGLE, 0, 0), (L_PLAN, 0, 1), (T_PLAN, 1, 2), (U_PLAN, 1, 3)],
                         ids=lambda v: str(v))
def test_the_plan_and_the_annex_switch_wings_on(gen, plan, annex, wings):
    x = _house(gen, template=plan, annex=annex, wing1_windows=2, wing2_windows=2, wing3_windows=2,
               wing1_floors=2, wing2_floors=2, wing3_floors=1)
    plain = gen.mesh(_house(gen), 2)
    m = gen.mesh(x, 2)
    whole = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert whole.is_watertight and whole.is_winding_consistent
    # each wing: its own core, roof and windows on both long sides
    assert np.sum(m.labels == ROOF) - np.sum(plain.labels == ROOF) == 16 * wings
    assert (np.sum(m.labels == WINDOWS) - np.sum(plain.labels == WINDOWS)) >= 12 * 2 * 2 * wings
    assert np.sum(m.labels == WALLS) > np.sum(plain.labels == WALLS) or not wings
    on = gen.active(x)
    for k in (1, 2, 3):
        assert on[gen.spec.index[f"wing{k}_length"]] == (k <= wings if plan != T_PLAN else k in (1, 3)), (PLANS[plan], k)


def _skeleton_heights(outline: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Height (wavefront time) of the straight skeleton roof of ``outline`` at ``points`` (x, z)."""
    from matplotlib.path import Path
    from py_straight_skeleton import compute_skeleton

    (ax, az), (bx, bz) = outline[1] - outline[0], outline[2] - outline[1]
    if ax * bz - az * bx < 0:  # counter-clockwise in (x, z)
        outline = outline[::-1]
    skeleton = compute_skeleton([tuple(map(float, p)) for p in outline], [])
    nodes = np.array([[n.position[0], n.position[1], n.time] for n in skeleton.nodes])
    out = np.full(len(points), np.nan)
    for face in skeleton.get_faces():
        corners = nodes[face[:-1]]
        inside = Path(corners[:, :2]).contains_points(points, radius=1e-9) & np.isnan(out)
        # the face is planar in (x, z, time): the plane through its corners
        a = np.c_[corners[:, :2], np.ones(len(corners))]
        coef = np.linalg.lstsq(a, corners[:, 2], rcond=None)[0]
        out[inside] = np.c_[points[inside], np.ones(inside.sum())] @ coef
    return out


@pytest.mark.parametrize("plan", [L_PLAN, T_PLAN, U_PLAN], ids=["L", "T", "U"])
def test_wing_roofs_of_one_pitch_meet_as_a_straight_skeleton(gen, plan):
    """Hipped roofs of one pitch over wings of one height: the roof over the union of the wings
    (what the depth test renders) is the straight skeleton roof of the plan's outline."""
    import open3d as o3d

    pitch, hx, hz, a, length = 0.8, 0.9, 0.5, 0.3, 0.7
    x = _house(gen, width=2 * hx, depth=2 * hz, roof_type=HIP, hip_ratio=1.0, roof_height=pitch * hz, template=plan,
               **{f"wing{k}_{n}": v for k in (1, 2) for n, v in
                  (("width", 2 * a), ("length", length), ("shift", 0.0), ("floors", 2), ("roof", HIP),
                   ("roof_height", pitch * a))})
    m = gen.mesh(x, 0)
    top = 0.6
    wings = {L_PLAN: [hx - a], T_PLAN: [0.0], U_PLAN: [-hx + a, hx - a]}[plan]
    outline = [(hx, hz), (-hx, hz), (-hx, -hz)]
    for c in sorted(wings):
        outline += [(c - a, -hz), (c - a, -hz - length), (c + a, -hz - length), (c + a, -hz)]
    outline = np.array(outline + [(hx, -hz)])
    outline = outline[np.r_[True, np.any(np.abs(np.diff(outline, axis=0)) > 1e-9, axis=1)]]  # flush corners once
    cells = (np.arange(60) + 0.5) / 60  # cell centres: no point on an outline's edge
    points = np.array([(px, pz) for px in -hx + 2 * hx * cells for pz in -hz - length + (2 * hz + length) * cells])
    expected = _skeleton_heights(outline, points)
    inside = ~np.isnan(expected)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.uint32))
    rays = np.c_[points[:, 0], np.full(len(points), 5.0), points[:, 1], np.zeros(len(points)), -np.ones(len(points)),
                 np.zeros(len(points))].astype(np.float32)
    height = 5.0 - scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy() - top
    assert inside.sum() > 1000
    np.testing.assert_allclose(height[inside], pitch * expected[inside], atol=2e-4)
