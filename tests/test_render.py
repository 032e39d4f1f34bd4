"""Mitsuba silhouettes: agree with an independent ray caster; gradients agree with finite differences."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ipm.generators import get_generator
from ipm.metrics import raycast_masks
from ipm.problem import Problem
from ipm.render.cameras import orbit_camera, project
from ipm.render.silhouette import SilhouetteRenderer
from tests.conftest import slow_except

FOV = 0.7


def _mug_problem():
    gen = get_generator("dishes")
    return gen, Problem(gen, np.zeros(3), 1.0)


def _cams():
    return np.stack([orbit_camera([0, 0.5, 0], 3.0, 20, 25), orbit_camera([0, 0.5, 0], 3.0, 110, 5)])


def test_mask_matches_ray_cast(variant):
    gen = get_generator("dishes")
    m = gen.mesh(gen.presets["mug"], 1)
    cams = _cams()
    mi_masks = SilhouetteRenderer(cams, FOV, 96, 96, spp=16).render(m.vertices, m.faces) > 0.5
    rc = raycast_masks(trimesh.Trimesh(m.vertices, m.faces, process=False), list(cams), res=96,
                       fov_deg=np.degrees(FOV))
    for a, b in zip(mi_masks, rc):
        iou = (a & b).sum() / (a | b).sum()
        assert iou > 0.97


def test_projection_matches_render(variant):
    """A point on the jar's axis projects inside its rendered silhouette (camera conventions agree)."""
    gen = get_generator("dishes")
    m = gen.mesh(gen.presets["jar"], 0)
    cams = _cams()
    masks = SilhouetteRenderer(cams, FOV, 64, 64, spp=8).render(m.vertices, m.faces)
    for c2w, mask in zip(cams, masks):
        for y, inside in ((0.6, True), (1.6, False)):
            px, py = project(np.array([[0.0, y, 0.0]]), c2w, FOV, 64, 64)[0]
            assert (mask[int(py), int(px)] > 0.5) == inside


POSE = ("yaw", "tilt_x", "tilt_z", "dx", "dy", "dz", "log_scale")


@pytest.mark.parametrize("name, shift, delta", slow_except([
    ("profile_4", 0.1, 0.005), ("y_scale", 0.1, 0.005), ("handle_radius_10", 0.3, 0.02),
    ("yaw", 0.3, 0.005), ("dx", 0.05, 0.005), ("log_scale", 0.05, 0.005),
], "profile_4"))
@pytest.mark.slow
def test_gradient_matches_central_differences(variant, name, shift, delta):
    """d loss / d z from Mitsuba + drjit.wrap(JAX) against central differences of the same loss.

    The target is the same mug with parameter ``name`` shifted, so the loss has a clear slope;
    ``delta`` moves the silhouette by a fraction of a pixel (more for the thin handle).
    """
    gen, problem = _mug_problem()
    z0 = problem.initial_z(gen.spec.to_unit(gen.presets["mug"]), 0.3)
    i = gen.spec.index[name] if name in gen.spec.index else problem.n_shape + POSE.index(name)
    key = problem.key(z0)
    topo, fn = gen.topology(key, 0), problem.vertex_fn(key, 0)
    renderer = SilhouetteRenderer(_cams(), FOV, 64, 64, spp=64)

    def render(z, seed):
        return renderer.render(np.asarray(fn(z)).reshape(-1, 3), topo.faces, seed=seed)

    zt = z0.copy()
    zt[i] += shift
    targets = render(zt, seed=7)
    grads = [renderer.loss_and_grad(fn, z0, topo.faces, topo.n_vertices, targets, seed=s)[1][i] for s in (1, 2)]
    zp, zm = z0.copy(), z0.copy()
    zp[i] += delta
    zm[i] -= delta
    fd = (np.mean((render(zp, 3) - targets) ** 2) - np.mean((render(zm, 3) - targets) ** 2)) / (2 * delta)
    assert fd < 0  # moving towards the target lowers the loss
    assert np.mean(grads) == pytest.approx(fd, rel=0.2)
