"""Buildings generator (the paper's third class, Figure 6): floors, window layouts, entrances,
balconies and roof shapes, in four levels of detail.

Everything is built from closed solids whose corners are affine in the parameters (boxes, and a
six-vertex prism for gable and hip roofs), so every part is watertight and the vertex positions
are a pure JAX function with a Jacobian; the discrete parameters (floors, windows per facade,
entrances, window split, roof type, balconies, chimney, steps) decide which solids exist.

Object frame: y up, ground at y = 0, the entrance facade facing +z, the footprint centred on the
y axis. Units: about 10 m per unit (a floor is 0.25-0.45 tall); pose scale carries the size.

Levels of detail (the paper's Figure 6): 0 a box with its roof; 1 outer walls: cornice, balcony
slabs and chimney added; 2 without small details: window and door openings recessed into the
walls with glass and door leaves, entrance steps, a flat roof's parapet; 3 full detail: window
frames and mullions, balcony railings, entrance canopies.
"""
from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from ipm.generators import GENERATORS
from ipm.generators.base import Generator, Topology, make_spec

PARTS = ("walls", "windows", "frames", "roof", "door", "balconies")
WALLS, WINDOWS, FRAMES, ROOF, DOOR, BALCONIES = range(len(PARTS))
FLAT, GABLE, HIP = range(3)
MIN_PIER = 0.03
"""Least wall between two openings and above an opening (object units)."""
GLASS = 0.003
"""Thickness of the glass and door leaves, set just in front of the recess's back."""
RAIL = 0.01
"""Thickness of balcony railings and parapets."""

_SPEC_ROWS = [
    # footprint and storeys
    ("width", 0.6, 2.0, False, 1.2), ("depth", 0.5, 1.6, False, 0.9),
    ("floor_height", 0.25, 0.45, False, 0.32), ("ground_extra", 0.0, 0.15, False, 0.04),
    # windows
    ("window_width", 0.06, 0.3, False, 0.14), ("window_height", 0.08, 0.3, False, 0.18),
    ("window_sill", 0.03, 0.12, False, 0.08), ("window_inset", 0.01, 0.05, False, 0.025),
    ("window_margin", 0.03, 0.3, False, 0.1), ("side_window_scale", 0.5, 1.5, False, 1.0),
    ("ground_window_scale", 0.7, 2.0, False, 1.0), ("ground_window_height", 0.08, 0.35, False, 0.2),
    ("frame_width", 0.005, 0.025, False, 0.012), ("frame_depth", 0.004, 0.03, False, 0.01),
    ("mullion_width", 0.004, 0.015, False, 0.008),
    # entrances
    ("door_width", 0.08, 0.3, False, 0.14), ("door_height", 0.15, 0.4, False, 0.26),
    ("canopy_depth", 0.02, 0.15, False, 0.06), ("canopy_overhang", 0.0, 0.06, False, 0.03),
    ("step_height", 0.01, 0.05, False, 0.02), ("step_depth", 0.02, 0.08, False, 0.04),
    # top of the walls and roof
    ("cornice_height", 0.01, 0.06, False, 0.03), ("cornice_offset", 0.0, 0.05, False, 0.02),
    ("roof_height", 0.05, 0.8, False, 0.35), ("roof_overhang", 0.0, 0.15, False, 0.05),
    ("roof_thickness", 0.02, 0.08, False, 0.04), ("hip_ratio", 0.2, 1.0, False, 0.6),
    ("parapet_height", 0.01, 0.1, False, 0.04),
    # balconies (entrance facade)
    ("balcony_depth", 0.05, 0.25, False, 0.12), ("balcony_width", 0.2, 1.0, False, 0.5),
    ("balcony_thickness", 0.015, 0.05, False, 0.025), ("railing_height", 0.05, 0.14, False, 0.1),
    # chimney (position as a share of the footprint)
    ("chimney_x", -0.4, 0.4, False, 0.25), ("chimney_z", -0.4, 0.4, False, 0.0),
    ("chimney_size", 0.04, 0.15, False, 0.08), ("chimney_height", 0.05, 0.4, False, 0.15),
    # discrete structure
    ("floors", 1, 8, True, 2), ("windows_front", 0, 8, True, 3), ("windows_back", 0, 8, True, 3),
    ("windows_left", 0, 8, True, 2), ("windows_right", 0, 8, True, 2), ("entrances", 1, 3, True, 1),
    ("window_split", 0, 2, True, 1), ("roof_type", 0, 2, True, GABLE), ("balconies", 0, 2, True, 0),
    ("balcony_start", 1, 7, True, 1), ("chimney", 0, 1, True, 0), ("steps", 0, 3, True, 1),
]
DISCRETE = [row[0] for row in _SPEC_ROWS if row[3]]

# corner c of a box has coordinate hi on axis k where bit k of c is set
_BITS = np.array([[(c >> k) & 1 for k in range(3)] for c in range(8)], bool)
_BOX_FACES = np.array([[0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5], [0, 1, 5], [0, 5, 4],
                       [2, 6, 7], [2, 7, 3], [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6]])
# eaves corners 0-3 (counter-clockwise seen from above, from -x -z), ridge ends 4 (-x) and 5 (+x)
_ROOF_FACES = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 5], [3, 5, 4], [1, 0, 4], [1, 4, 5],
                        [0, 3, 4], [2, 1, 5]])
# facades: along-facade direction and outward normal (the footprint's +z side has the entrances)
_FACADES = {"front": ((1, 0, 0), (0, 0, 1)), "back": ((-1, 0, 0), (0, 0, -1)),
            "right": ((0, 0, -1), (1, 0, 0)), "left": ((0, 0, 1), (-1, 0, 0))}


def _interleave(n_windows: int, n_doors: int) -> np.ndarray:
    """Which of ``n_windows + n_doors`` evenly spaced slots hold doors (spread evenly)."""
    n = n_windows + n_doors
    is_door = np.zeros(n, bool)
    is_door[np.round((np.arange(n_doors) + 0.5) * n / n_doors - 0.5).astype(int)] = True
    return is_door


class _Solids:
    """Collects closed solids per part: boxes as (lo, hi) corner pairs, roofs as 6 vertices."""

    def __init__(self):
        self.groups: list[tuple[str, int, jnp.ndarray]] = []

    def boxes(self, part: int, a: jnp.ndarray, b: jnp.ndarray) -> None:
        """Axis-aligned boxes spanned by opposite corners ``a``, ``b`` (..., 3)."""
        a, b = jnp.reshape(a, (-1, 3)), jnp.reshape(b, (-1, 3))
        if a.shape[0]:
            lo = jnp.minimum(a, b)
            hi = jnp.maximum(jnp.maximum(a, b), lo + 1e-3)  # never flat
            self.groups.append(("box", part, jnp.where(_BITS[None], hi[:, None, :], lo[:, None, :])))

    def prism(self, part: int, vertices: jnp.ndarray) -> None:
        self.groups.append(("roof", part, vertices[None]))


def _facade_boxes(s: _Solids, p, facade: str, length, origin, n_open: int, floors: int, lod: int,
                  ground: dict) -> None:
    """Walls, openings, glass, frames and mullions of one facade, every floor.

    Local coordinates: ``a`` along the facade (centred), ``y`` up, ``d`` into the building from
    the wall plane. ``ground``: the ground floor's slots (which hold doors), the entrance steps
    and the window split.
    """
    along, normal = (np.asarray(v, np.float32) for v in _FACADES[facade])
    up = np.array([0.0, 1.0, 0.0], np.float32)

    def world(a, y, d):
        a, y, d = jnp.broadcast_arrays(a, y, d)
        return origin + a[..., None] * along + y[..., None] * up - d[..., None] * normal

    def put(part, a0, a1, y0, y1, d0, d1):
        s.boxes(part, world(a0, y0, d0), world(a1, y1, d1))

    inset, half = p("window_inset"), 0.5 * length
    fh, g = p("floor_height"), p("ground_extra")
    # the ground floor, then every upper floor at once (arrays of shape (floors - 1, openings))
    for ground_floor, storeys in ((True, np.array([0])), (False, np.arange(1, floors))):
        if not len(storeys):
            continue
        f = storeys[:, None].astype(np.float32)
        is_door = ground["is_door"] if ground_floor else np.zeros(n_open, bool)
        y_base = 0.0 * f if ground_floor else f * fh + g
        y_top = (f + 1) * fh + g
        height = y_top - y_base
        n = len(is_door)
        if n == 0:
            put(WALLS, -half, half, y_base, y_top, 0.0, inset)
            continue
        margin = jnp.minimum(p("window_margin"), half - 0.5 * MIN_PIER)
        slot = (length - 2 * margin) / n
        centre = -half + margin + (np.arange(n) + 0.5) * slot
        scale = p("side_window_scale") if facade in ("left", "right") else 1.0
        if ground_floor:
            scale = scale * p("ground_window_scale")
        w_win = jnp.minimum(p("window_width") * scale, slot - MIN_PIER)
        w = jnp.where(is_door, jnp.minimum(p("door_width"), slot - MIN_PIER), w_win)
        sill = p("window_sill")
        win_h = p("ground_window_height") if ground_floor else p("window_height")
        y0_win = y_base + sill
        y1_win = y0_win + jnp.minimum(win_h, height - sill - MIN_PIER)
        door_y0 = ground["door_y0"]
        door_y1 = door_y0 + jnp.minimum(p("door_height"), height - door_y0 - MIN_PIER)
        y0 = jnp.where(is_door, door_y0, y0_win)
        y1 = jnp.where(is_door, door_y1, y1_win)
        a0, a1 = centre - 0.5 * w, centre + 0.5 * w
        # piers between openings (full storey), then the wall below and above each opening
        put(WALLS, jnp.concatenate([jnp.array([-half]), a1]), jnp.concatenate([a0, jnp.array([half])]),
            y_base, y_top, 0.0, inset)
        below = ~is_door | (ground["steps"] > 0)
        put(WALLS, a0[below], a1[below], y_base, y0[..., below], 0.0, inset)
        put(WALLS, a0, a1, y1, y_top, 0.0, inset)
        for part, mask in ((WINDOWS, ~is_door), (DOOR, is_door)):
            put(part, a0[mask], a1[mask], y0[..., mask], y1[..., mask], inset - GLASS, inset)
        if lod >= 3:
            fw, fd = p("frame_width"), p("frame_depth")
            back = inset - GLASS
            # frames wrap the opening's edges, so no frame face lies in a wall face
            yf = jnp.where(is_door, y0, y0 - fw)  # a door's frame stands on its threshold
            put(FRAMES, a0 - fw, a0 + fw, yf, y1 + fw, -fd, back)
            put(FRAMES, a1 - fw, a1 + fw, yf, y1 + fw, -fd, back)
            put(FRAMES, a0 - fw, a1 + fw, y1 - fw, y1 + fw, -fd, back)
            win = ~is_door
            put(FRAMES, a0[win] - fw, a1[win] + fw, y0[..., win] - fw, y0[..., win] + fw, -fd, back)
            split, mw = ground["split"], 0.5 * p("mullion_width")
            mid_a, mid_y = 0.5 * (a0 + a1), 0.5 * (y0 + y1)
            if split >= 1:
                put(FRAMES, mid_a[win] - mw, mid_a[win] + mw, y0[..., win], y1[..., win], back - 2 * GLASS, back)
            if split >= 2:
                put(FRAMES, a0[win], a1[win], mid_y[..., win] - mw, mid_y[..., win] + mw, back - 2 * GLASS, back)
        if ground_floor and is_door.any():
            dl, dr, dt = a0[is_door], a1[is_door], y1[..., is_door]
            if lod >= 2:
                for k in range(ground["steps"]):  # the lowest step reaches farthest out
                    put(WALLS, dl - 0.02, dr + 0.02, 0.0, door_y0 - k * p("step_height"),
                        -(k + 1) * p("step_depth"), inset)
            if lod >= 3:
                over = p("canopy_overhang")
                put(WALLS, dl - over, dr + over, dt + 0.02, dt + 0.035, -p("canopy_depth"), 0.0)


@GENERATORS.register("buildings")
class Buildings(Generator):
    """Houses and blocks: storeys of windows on four facades, entrances, balconies and a roof."""

    name = "buildings"
    spec = make_spec(_SPEC_ROWS)
    part_names = PARTS
    lods = (0, 1, 2, 3)
    reference_lod = 3
    presets = {}  # filled below from named edits of the defaults

    def topology_key(self, x):
        return tuple(int(round(float(x[self.spec.index[n]]))) for n in DISCRETE)

    def _structure(self, key: tuple) -> dict:
        s = dict(zip(DISCRETE, key))
        s["balcony_floors"] = (list(range(1, s["floors"])) if s["balconies"] == 1 else
                               list(range(s["balcony_start"], s["floors"])) if s["balconies"] == 2 else [])
        return s

    def sample(self, rng):
        """A random plausible building (the sampler of in-family cases), not a preset: footprint
        0.7-1.8 by 0.6-1.4, 1-6 storeys (fewer more likely), windows per facade from the facade's
        length and a spacing of 0.18-0.4 (a blank side wall with probability 1/3), 1-2 entrances,
        any roof type, balconies on every storey or from one up with probability 1/2, a chimney on
        half the pitched roofs; every other parameter uniform over its range."""
        spec, ix = self.spec, self.spec.index
        x = spec.from_unit(rng.random(len(spec)))
        w, d = rng.uniform(0.7, 1.8), rng.uniform(0.6, 1.4)
        floors = int(rng.choice(np.arange(1, 7), p=np.array([3, 4, 3, 2, 1, 1]) / 14))
        spacing = rng.uniform(0.18, 0.4)
        values = {"width": w, "depth": d, "floors": floors, "floor_height": rng.uniform(0.28, 0.4),
                  "window_width": rng.uniform(0.08, 0.6 * spacing), "window_margin": rng.uniform(0.05, 0.15),
                  "entrances": int(rng.choice([1, 1, 2])), "roof_type": int(rng.integers(3)),
                  "balconies": int(rng.choice([0, 0, 1, 2])) if floors > 1 else 0,
                  "balcony_start": int(rng.integers(1, max(floors - 1, 1) + 1)), "steps": int(rng.integers(0, 3))}
        for facade, length in (("front", w), ("back", w), ("left", d), ("right", d)):
            blank = facade in ("left", "right") and rng.random() < 1 / 3
            values[f"windows_{facade}"] = 0 if blank else int(np.clip(round(length / spacing), 1, 8))
        values["windows_front"] = max(values["windows_front"] - values["entrances"], 0)
        values["chimney"] = int(values["roof_type"] != FLAT and rng.random() < 0.5)
        for name, v in values.items():
            x[ix[name]] = v
        return spec.clip(x)

    def active(self, x):
        """Parameters of parts the object does not have are inert (a flat roof's slope, ...)."""
        s = self._structure(self.topology_key(x))
        off = set()
        if s["roof_type"] == FLAT:
            off.add("roof_height")
        else:
            off |= {"roof_thickness", "parapet_height"}
        if s["roof_type"] != HIP:
            off.add("hip_ratio")
        if not s["balcony_floors"]:
            off |= {"balcony_depth", "balcony_width", "balcony_thickness", "railing_height"}
        if s["balconies"] != 2:
            off.add("balcony_start")
        if not s["chimney"]:
            off |= {"chimney_x", "chimney_z", "chimney_size", "chimney_height"}
        if not s["steps"]:
            off |= {"step_height", "step_depth"}
        if not s["window_split"]:
            off.add("mullion_width")
        if not (s["windows_left"] or s["windows_right"]):
            off.add("side_window_scale")
        on = np.ones(len(self.spec), bool)
        on[[self.spec.index[n] for n in off]] = False
        return on

    def _solids(self, x, key: tuple, lod: int) -> _Solids:
        """Every solid of the building ``x`` (jnp vector) with topology ``key`` at ``lod``."""
        ix = self.spec.index

        def p(name):
            return x[ix[name]]

        s = self._structure(key)
        out = _Solids()
        w, d = p("width"), p("depth")
        hx, hz = 0.5 * w, 0.5 * d
        top = s["floors"] * p("floor_height") + p("ground_extra")
        inset = p("window_inset") if lod >= 2 else 0.0
        out.boxes(WALLS, jnp.stack([-hx + inset, 0.0, -hz + inset]), jnp.stack([hx - inset, top, hz - inset]))
        if lod >= 2:
            ground = {"is_door": _interleave(s["windows_front"], s["entrances"]), "steps": s["steps"],
                      "door_y0": s["steps"] * p("step_height"), "split": s["window_split"]}
            side = d - 2 * inset  # side facades run between the front and back walls
            for facade, length, origin, n in (
                    ("front", w, jnp.stack([0.0, 0.0, hz]), s["windows_front"]),
                    ("back", w, jnp.stack([0.0, 0.0, -hz]), s["windows_back"]),
                    ("right", side, jnp.stack([hx, 0.0, 0.0]), s["windows_right"]),
                    ("left", side, jnp.stack([-hx, 0.0, 0.0]), s["windows_left"])):
                no_doors = {**ground, "is_door": np.zeros(n, bool), "steps": 0}
                _facade_boxes(out, p, facade, length, origin, n, s["floors"], lod,
                              ground if facade == "front" else no_doors)
        if lod >= 1:
            co, ch = p("cornice_offset"), p("cornice_height")
            out.boxes(WALLS, jnp.stack([-hx - co, top - ch, -hz - co]), jnp.stack([hx + co, top, hz + co]))
            fh, g = p("floor_height"), p("ground_extra")
            bw, bd = 0.5 * p("balcony_width") * w, p("balcony_depth")
            bt, rh = p("balcony_thickness"), p("railing_height")
            for f in s["balcony_floors"]:
                y = f * fh + g
                out.boxes(BALCONIES, jnp.stack([-bw, y - bt, hz - inset]), jnp.stack([bw, y, hz + bd]))
                if lod >= 3:
                    out.boxes(BALCONIES, jnp.stack([-bw, y, hz + bd - RAIL]), jnp.stack([bw, y + rh, hz + bd]))
                    out.boxes(BALCONIES, jnp.stack([-bw, y, hz]), jnp.stack([-bw + RAIL, y + rh, hz + bd - RAIL]))
                    out.boxes(BALCONIES, jnp.stack([bw - RAIL, y, hz]), jnp.stack([bw, y + rh, hz + bd - RAIL]))
        o = p("roof_overhang")
        ex, ez = hx + o, hz + o
        if s["roof_type"] == FLAT:
            rt = p("roof_thickness")
            out.boxes(ROOF, jnp.stack([-ex, top, -ez]), jnp.stack([ex, top + rt, ez]))
            ridge = top + rt
            if lod >= 2:
                ph = ridge + p("parapet_height")
                out.boxes(ROOF, jnp.stack([-ex, ridge, ez - RAIL]), jnp.stack([ex, ph, ez]))
                out.boxes(ROOF, jnp.stack([-ex, ridge, -ez]), jnp.stack([ex, ph, -ez + RAIL]))
                out.boxes(ROOF, jnp.stack([ex - RAIL, ridge, -ez + RAIL]), jnp.stack([ex, ph, ez - RAIL]))
                out.boxes(ROOF, jnp.stack([-ex, ridge, -ez + RAIL]), jnp.stack([-ex + RAIL, ph, ez - RAIL]))
        else:
            ridge = top + p("roof_height")
            half_ridge = ex if s["roof_type"] == GABLE else jnp.maximum(ex - p("hip_ratio") * ez, 0.01)
            out.prism(ROOF, jnp.stack([jnp.stack([-ex, top, -ez]), jnp.stack([ex, top, -ez]),
                                       jnp.stack([ex, top, ez]), jnp.stack([-ex, top, ez]),
                                       jnp.stack([-half_ridge, ridge, 0.0]), jnp.stack([half_ridge, ridge, 0.0])]))
        if lod >= 1 and s["chimney"]:
            cx, cz, cs = p("chimney_x") * w, p("chimney_z") * d, 0.5 * p("chimney_size")
            out.boxes(ROOF, jnp.stack([cx - cs, top, cz - cs]), jnp.stack([cx + cs, ridge + p("chimney_height"), cz + cs]))
        return out

    @lru_cache(maxsize=None)
    def topology(self, key, lod):
        x = self.spec.default.copy()
        for name, v in zip(DISCRETE, key):
            x[self.spec.index[name]] = v
        kinds = []  # (kind, part, solids, vertices per solid), recorded while tracing (no compile)
        jax.eval_shape(lambda z: kinds.extend((k, part, *v.shape[:2]) for k, part, v in
                                              self._solids(z, key, lod).groups), jnp.asarray(x, jnp.float32))
        faces, labels, offset = [], [], 0
        for kind, part, n, k in kinds:
            template = _BOX_FACES if kind == "box" else _ROOF_FACES
            faces.append((template[None] + (offset + k * np.arange(n))[:, None, None]).reshape(-1, 3))
            labels.append(np.full(n * len(template), part, np.int32))
            offset += n * k
        v = np.asarray(self.positions_fn(key, lod)(jnp.asarray(x, jnp.float32)), np.float64)
        fh = float(x[self.spec.index["floor_height"]])
        uv = np.stack([(v[:, 0] + v[:, 2]) / fh, v[:, 1] / fh], 1)  # one texture tile per storey
        return Topology(np.concatenate(faces).astype(np.int64), np.concatenate(labels), uv)

    @lru_cache(maxsize=None)
    def positions_fn(self, key, lod):
        def positions(x):
            groups = self._solids(x, key, lod).groups
            return jnp.concatenate([g[2].reshape(-1, 3) for g in groups]).astype(jnp.float32)

        return jax.jit(positions)


def _preset(**values) -> np.ndarray:
    return Buildings.spec.from_dict(values)


Buildings.presets = {
    "house": _preset(floors=2, windows_front=2, windows_back=3, windows_left=1, windows_right=1,
                     roof_type=GABLE, roof_height=0.35, chimney=1),
    "villa": _preset(width=1.6, depth=1.2, floors=2, windows_front=4, windows_back=4, windows_left=2,
                     windows_right=2, roof_type=HIP, roof_height=0.3, hip_ratio=0.8, window_split=2,
                     balconies=2, balcony_start=1, steps=2),
    "townhouse": _preset(width=0.9, depth=1.0, floors=4, windows_front=3, windows_back=3, windows_left=0,
                         windows_right=0, roof_type=FLAT, balconies=1, balcony_width=0.8, steps=1),
    "tower": _preset(width=1.2, depth=1.2, floor_height=0.3, floors=8, windows_front=5, windows_back=5,
                     windows_left=5, windows_right=5, roof_type=FLAT, window_split=0, ground_window_scale=1.6,
                     entrances=2, steps=0, parapet_height=0.06),
}
