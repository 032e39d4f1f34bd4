"""Dishes generator (paper, Figure 5; the authors' 53-parameter layout: ``docs/design``,
"Generators").

1. a profile spline from 9 radial offsets at equally spaced heights;
2. a closed profile: outer wall, flat rim, inner wall (at every height the wall thickness inside the
   outer one, so the two never cross where the profile lies flat), inner and outer bottom;
3. revolved about +y into the body (a closed surface between two poles);
4. optionally a handle: a C-shaped spline of 20 control points around a centre at
   ``handle_height`` on the body surface (distances ``handle_radius_k``), swept by a tube whose
   radius is ``handle_thickness * handle_thick_coef_k``, capped at both ends inside the wall.
Object frame: y up, the base at y = 0, the handle on the +x side. Sizes are in units where a
mug is about 1 tall; pose scale carries the absolute size.
"""
from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from ipm.generators.base import GENERATORS, Generator, Topology, make_spec
from ipm.generators.geometry import (catmull_rom_at, catmull_rom_matrix, closed_sweep_faces,
                                     revolve, sweep_tube)
from ipm.uv import sweep_atlas, sweep_uv

N_PROFILE, N_HANDLE = 9, 20
_HANDLE_SIN = np.sin(np.pi * (np.linspace(0.0, 1.0, N_HANDLE) - 0.5))
"""Height of each handle control point above the handle's centre, per unit of its distance."""
WALL = 0.03
"""Wall thickness of the body (object units): inner radius = r - WALL * r / (r + WALL) > 0."""
BOTTOM = 0.03
"""Thickness of the bottom (object units), at most a quarter of the height."""
PROFILE_UNIT = 0.1
"""Object units per profile offset unit (offsets 0.1..8 give radii 0.01..0.8)."""


def _inner(r):
    """The inner wall's radius inside an outer radius ``r`` at the same height (numpy or JAX)."""
    return r - WALL * r / (r + WALL)


_SPEC_ROWS = (
    [(f"profile_{i}", 0.1, 8.0, False, 4.0) for i in range(N_PROFILE)]
    + [("y_scale", 0.1, 1.25, False, 1.0), ("has_handle", 0.0, 1.0, True, 1.0),
       ("handle_thickness", 0.025, 0.075, False, 0.05), ("handle_height", 0.3, 0.7, False, 0.5)]
    + [(f"handle_radius_{i}", 0.1, 0.5, False, 0.3) for i in range(N_HANDLE)]
    + [(f"handle_thick_coef_{i}", 0.1, 2.0, False, 1.0) for i in range(N_HANDLE)]
)

# (profile points, ring points, handle samples, handle ring points) per level of detail
_LOD = {0: (24, 32, 24, 8), 1: (40, 64, 40, 12), 2: (80, 128, 80, 16)}


def _body_rows(n_p: int) -> np.ndarray:
    """v of the body's rows along its unrolled profile, by the presets' mean lengths: the outer wall
    by height, the rim, the inner wall down to the bottom (the same v at a profile point at every
    level of detail)."""
    h, rim, bottom = _MEAN["height"], _MEAN["rim"], _MEAN["bottom"]
    t = np.linspace(0.0, 1.0, n_p)
    length = 2 * h + rim - bottom
    return np.concatenate([t * h, h + rim + t * (h - bottom)]) / length


@lru_cache(maxsize=None)
def _atlases():
    """The body's and the handle's charts (``ipm.uv.sweep_atlas``), sized by the presets' means: the
    body's profile unrolled round its mean circumference, the outer and inner bottoms as discs; the
    handle's tube round its mean girth along its mean length, its two end caps."""
    m = _MEAN
    body = sweep_atlas((2 * np.pi * m["radius"], 2 * m["height"] + m["rim"] - m["bottom"]),
                       (m["base_out"], m["base_in"]))
    handle = sweep_atlas((2 * np.pi * m["tube"], m["path"]), (m["tube"], m["tube"]))
    return body, handle


def power_profile(t, r0: float, r1: float, gamma: float, bulge: float) -> np.ndarray:
    """Profile offsets at heights ``t`` (0 at the base, 1 at the rim) from ``r0`` to ``r1`` by the
    power curve ``t**gamma``, with a bulge (a waist where negative) of ``bulge`` at mid-height, kept
    within 0.3-8."""
    return np.clip(r0 + (r1 - r0) * t**gamma + bulge * np.sin(np.pi * t), 0.3, 8.0)


def _preset_means(presets: dict) -> dict:
    """Mean sizes of the presets' parts (object units), which fix the charts' proportions."""
    w = catmull_rom_matrix(N_PROFILE, 64)
    rows = []
    for x in presets.values():
        r = np.maximum(w @ (PROFILE_UNIT * x[:N_PROFILE]), 0.005)
        r_in = _inner(r)
        h = x[N_PROFILE]
        rows.append({"radius": r.mean(), "height": h, "rim": r[-1] - r_in[-1], "bottom": min(BOTTOM, 0.25 * h),
                     "base_out": r[0], "base_in": r_in[0]})
        if x[N_PROFILE + 1] > 0.5:
            i = N_PROFILE + 4
            rows[-1] |= {"tube": x[N_PROFILE + 2] * x[i + N_HANDLE:i + 2 * N_HANDLE].mean(),
                         "path": np.pi * x[i:i + N_HANDLE].mean() * h}
    return {k: float(np.mean([r[k] for r in rows if k in r])) for k in rows[0] | rows[-1]}


def _preset(spec, profile, y_scale, handle=None):
    x = spec.default.copy()
    x[:N_PROFILE] = profile
    x[spec.index["y_scale"]] = y_scale
    x[spec.index["has_handle"]] = 0.0 if handle is None else 1.0
    if handle is not None:
        thickness, height, radius = handle
        x[spec.index["handle_thickness"]] = thickness
        x[spec.index["handle_height"]] = height
        x[spec.index["handle_radius_0"]:spec.index["handle_radius_0"] + N_HANDLE] = radius
    return x


@GENERATORS.register("dishes")
class Dishes(Generator):
    """Cups, mugs, bowls and jars: a revolved body with an optional swept handle."""

    name = "dishes"
    spec = make_spec(_SPEC_ROWS)
    part_names = ("body", "handle")
    lods = tuple(_LOD)
    simplest = {"has_handle": 0.0}
    """Discrete values to prefer when the views cannot tell (``ipm.search.moves.simplify``)."""
    moves = ("polish", "handle side", "simplify")
    """Polish, the handle's side by the colour image and the Occam step that drops a handle the views
    do not show (``ipm.search.moves``)."""
    sided_part = "handle"
    smooth_groups = ((0, N_PROFILE, 0.05, 2), (13, 13 + N_HANDLE, 1.0, 2), (13 + N_HANDLE, 13 + 2 * N_HANDLE, 1.0, 2))
    """(start, stop, relative weight, difference order) of the control sequences under the smoothness prior: the
    handle's radii and thickness (one view barely constrains them), and lightly the profile (a
    sudden inward kink at the rim would fake an open rim seen from above with a closed lid)."""
    presets = {
        "mug": _preset(spec, [3.8, 3.9, 3.95, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0], 1.0, (0.05, 0.5, 0.3)),
        "tea_cup": _preset(spec, [2.2, 2.6, 3.1, 3.6, 4.0, 4.4, 4.7, 4.9, 5.0], 0.55, (0.035, 0.55, 0.2)),
        "bowl": _preset(spec, [2.5, 4.2, 5.3, 6.1, 6.6, 7.0, 7.3, 7.5, 7.6], 0.45),
        "jar": _preset(spec, [3.5, 4.2, 4.5, 4.4, 4.0, 3.2, 2.6, 2.6, 2.9], 1.2),
    }

    def topology_key(self, x):
        return (int(round(float(x[self.spec.index["has_handle"]]))),)

    def active(self, x):
        """Without a handle, the handle's parameters are inert."""
        on = np.ones(len(self.spec), bool)
        if not self.topology_key(x)[0]:
            on[self.spec.index["handle_thickness"]:] = False
        return on

    def feasible(self, x):
        """A handle hangs on the wall between the base and the rim (every sampled and every real
        cup's does; one reaching below the base would stand the cup on it): each control point's
        distance from the handle's centre is held so that its point of the C, with the tube round
        it, lies within the body's height (the distances' lower bound wins where nothing fits)."""
        ix = self.spec.index
        if not self.topology_key(x)[0]:
            return x
        i_h, i_c = ix["handle_radius_0"], ix["handle_thick_coef_0"]
        height, rho = x[ix["y_scale"]], x[i_h:i_h + N_HANDLE]
        centre, tube = x[ix["handle_height"]] * height, x[ix["handle_thickness"]] * x[i_c:i_c + N_HANDLE]
        room = np.where(_HANDLE_SIN < 0, centre - tube, height - centre - tube)
        reach = np.maximum(room / (height * np.abs(_HANDLE_SIN)), self.spec.lower[i_h:i_h + N_HANDLE])
        if np.all(rho <= reach):
            return x
        out = np.array(x, np.float64)
        out[i_h:i_h + N_HANDLE] = np.minimum(rho, reach)
        return out

    def yaw_symmetric(self, x):
        """A body of revolution without a handle."""
        return not self.topology_key(x)[0]

    def texture_symmetry(self, part: int, res: int) -> np.ndarray:
        """A part's texels grouped by the revolution (``ipm.texture.fill``): a row of the unrolled
        body or tube (one height round the axis), a ring of a bottom or cap disc."""
        (u0, v0, u1, v1), discs = _atlases()[part]
        v, u = np.meshgrid(1 - (np.arange(res) + 0.5) / res, (np.arange(res) + 0.5) / res, indexing="ij")
        groups = np.full((res, res), -1)
        strip = (u >= u0) & (u <= u1) & (v >= v0) & (v <= v1)
        groups[strip] = np.round(v[strip] * res).astype(int)
        for k, (cu, cv, r) in enumerate(discs):
            radius = np.hypot(u - cu, v - cv)
            disc = radius <= r
            groups[disc] = res * (k + 1) + np.round(radius[disc] * res).astype(int)
        return groups

    def sample(self, rng, handle: bool | None = None):
        """A random plausible vessel (the test split's sampler), not a preset: a smooth profile from
        a base and a rim radius (0.15-0.5 and 0.15-0.75 object units) joined by a power curve with a
        bulge or waist, height 0.35-1.2, and (with probability 1/2, or as ``handle`` says) a C- or
        D-shaped handle whose ends stay on the body, with smooth radius and thickness sequences."""
        spec, ix = self.spec, self.spec.index
        x = spec.default.copy()
        t = np.linspace(0.0, 1.0, N_PROFILE)
        r0, r1 = rng.uniform(1.5, 5.0), rng.uniform(1.5, 7.5)
        gamma = float(np.exp(rng.uniform(np.log(0.4), np.log(2.5))))
        bulge = rng.uniform(-1.0, 1.5)
        x[:N_PROFILE] = power_profile(t, r0, r1, gamma, bulge)
        x[ix["y_scale"]] = rng.uniform(0.35, 1.2)
        with_handle = bool(rng.random() < 0.5) if handle is None else bool(handle)
        x[ix["has_handle"]] = float(with_handle)
        if with_handle:
            height = rng.uniform(0.4, 0.6)
            s = np.linspace(0.0, 1.0, N_HANDLE)
            thickness = rng.uniform(0.03, 0.07)
            coef = np.clip(1.0 + rng.uniform(-0.3, 0.5) * np.sin(np.pi * s) + rng.uniform(-0.4, 0.4) * (s - 0.5),
                           0.3, 2.0)
            # largest offset of the handle's ends from its centre that keeps the tube on the body
            reach = max(min(height, 1.0 - height) - thickness * coef.max() / x[ix["y_scale"]] - 0.02, 0.12)
            base = rng.uniform(0.12, max(reach, 0.15))
            rho = base * (1.0 + rng.uniform(-0.3, 0.3) * (s - 0.5) + rng.uniform(-0.2, 0.4) * np.sin(np.pi * s))
            rho *= min(1.0, reach / np.max(rho * np.abs(np.cos(np.pi * s))))  # the ends' heights: +-rho cos
            x[ix["handle_thickness"]] = thickness
            x[ix["handle_height"]] = height
            x[ix["handle_radius_0"]:ix["handle_radius_0"] + N_HANDLE] = np.clip(rho, 0.1, 0.5)
            x[ix["handle_thick_coef_0"]:ix["handle_thick_coef_0"] + N_HANDLE] = coef
        return spec.clip(x)

    @lru_cache(maxsize=None)
    def topology(self, key, lod):
        n_p, n_r, n_s, n_c = _LOD[lod]
        rows = 2 * n_p
        faces = [closed_sweep_faces(rows, n_r)[:, ::-1]]  # outward for the y-up revolve
        labels = [np.zeros(len(faces[0]), np.int32)]
        body, handle = _atlases()
        uv = [sweep_uv(faces[0], rows, n_r, 0, _body_rows(n_p), *body)]
        if key[0]:
            offset = rows * n_r + 2
            faces.append(closed_sweep_faces(n_s, n_c, offset))
            labels.append(np.ones(len(faces[-1]), np.int32))
            uv.append(sweep_uv(faces[-1], n_s, n_c, offset, np.linspace(0.0, 1.0, n_s), *handle))
        n_vertices = rows * n_r + 2 + (n_s * n_c + 2 if key[0] else 0)
        return Topology(np.concatenate(faces), np.concatenate(labels), lambda: np.concatenate(uv), n_vertices)

    @lru_cache(maxsize=None)
    def positions_fn(self, key, lod):
        n_p, n_r, n_s, n_c = _LOD[lod]
        w_profile = jnp.asarray(catmull_rom_matrix(N_PROFILE, n_p), jnp.float32)
        w_handle = jnp.asarray(catmull_rom_matrix(N_HANDLE, n_s), jnp.float32)
        t = jnp.linspace(0.0, 1.0, n_p)
        ix = self.spec.index
        i_h = ix["handle_radius_0"]
        i_c = ix["handle_thick_coef_0"]
        with_handle = bool(key[0])

        def positions(x):
            height = x[ix["y_scale"]]
            ctrl = PROFILE_UNIT * x[:N_PROFILE]
            r_out = jnp.maximum(w_profile @ ctrl, 0.005)
            radius_at = jax.vmap(lambda yy: jnp.maximum(catmull_rom_at(ctrl, yy / height), 0.005))  # outer, at heights
            bottom = jnp.minimum(BOTTOM, 0.25 * height)
            y_out = t * height
            y_in = bottom + t * (height - bottom)
            r_in = _inner(radius_at(y_in))
            radius = jnp.concatenate([r_out, r_in[::-1]])
            ys = jnp.concatenate([y_out, y_in[::-1]])
            parts = [jnp.zeros((1, 3)), revolve(radius, ys, n_r), jnp.stack([0.0, bottom, 0.0])[None]]
            if with_handle:
                s = jnp.linspace(0.0, 1.0, N_HANDLE)
                phi = -0.5 * np.pi + np.pi * s
                rho = x[i_h:i_h + N_HANDLE] * height
                centre_y = x[ix["handle_height"]] * height
                cy = centre_y + rho * jnp.sin(phi)
                cx = radius_at(cy) - 0.5 * WALL + rho * jnp.cos(phi)
                path_ctrl = jnp.stack([cx, cy, jnp.zeros_like(cx)], 1)
                path = w_handle @ path_ctrl
                tube_r = x[ix["handle_thickness"]] * (w_handle @ x[i_c:i_c + N_HANDLE])
                tube_r = jnp.maximum(tube_r, 0.002)
                parts += [path[:1], sweep_tube(path, tube_r, n_c), path[-1:]]
            return jnp.concatenate(parts).astype(jnp.float32)

        return jax.jit(positions)


_MEAN = _preset_means(Dishes.presets)
"""Mean sizes of the presets' parts, which fix the charts' proportions (``_atlases``)."""
