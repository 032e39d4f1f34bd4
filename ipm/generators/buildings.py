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

The module is past 450 lines because the parameter table, the solids of every level and the
facade geometry the search's moves read (facades, the door's extent, count changes, roof splits)
describe one object and change together.
"""
from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from ipm.generators.base import GENERATORS, Generator, Topology, make_spec
from ipm.io.semantic import BUILDING_LABELS

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
_TEMPLATES = {"box": _BOX_FACES, "roof": _ROOF_FACES}
# facades: along-facade direction and outward normal (the footprint's +z side has the entrances)
_FACADES = {"front": ((1, 0, 0), (0, 0, 1)), "back": ((-1, 0, 0), (0, 0, -1)),
            "right": ((0, 0, -1), (1, 0, 0)), "left": ((0, 0, 1), (-1, 0, 0))}


def _largest(name: str) -> int:
    return int(dict((row[0], row[2]) for row in _SPEC_ROWS)[name])


MAX_FLOORS, MAX_WINDOWS, MAX_ENTRANCES, MAX_STEPS = (_largest(n) for n in ("floors", "windows_front", "entrances", "steps"))


class _Solids:
    """Collects closed solids per part at their largest count, each with a flag saying whether
    the building has it: boxes as (lo, hi) corner pairs, roofs as 6 vertices. Parts and flags may
    be traced values; the topology keeps the flagged solids, the positions function all of them,
    so one compiled function serves every topology of a level of detail."""

    def __init__(self):
        self.groups: list[tuple[str, jnp.ndarray, jnp.ndarray, jnp.ndarray]] = []

    def boxes(self, part, a: jnp.ndarray, b: jnp.ndarray, valid=True) -> None:
        """Axis-aligned boxes spanned by opposite corners ``a``, ``b`` (..., 3); ``part`` and
        ``valid`` broadcast to their count."""
        a, b = jnp.broadcast_arrays(a, b)
        lead = a.shape[:-1]
        a, b = a.reshape(-1, 3), b.reshape(-1, 3)
        lo = jnp.minimum(a, b)
        hi = jnp.maximum(jnp.maximum(a, b), lo + 1e-3)  # never flat
        self.groups.append(("box", jnp.broadcast_to(part, lead).ravel(), jnp.broadcast_to(valid, lead).ravel(),
                            jnp.where(_BITS[None], hi[:, None, :], lo[:, None, :])))

    def prism(self, part: int, vertices: jnp.ndarray, valid=True) -> None:
        self.groups.append(("roof", jnp.full(1, part), jnp.reshape(valid, (1,)), vertices[None]))


def _wall_top(p):
    """Height of the walls' top (the storeys and the ground floor's extra), ``p`` a parameter's
    value by name: one formula for the mesh, the facades and the roof split."""
    return p("floors") * p("floor_height") + p("ground_extra")


def _door_slots(n, n_doors, slots: int) -> jnp.ndarray:
    """Which of ``n`` evenly spaced slots (of ``slots`` at most) hold the ``n_doors`` doors,
    spread evenly: slot ``round((k + 1/2) n / n_doors - 1/2)`` for door k."""
    k = jnp.arange(MAX_ENTRANCES, dtype=jnp.float32)[:, None]
    at = jnp.round((k + 0.5) * n / jnp.maximum(n_doors, 1.0) - 0.5)
    j = jnp.arange(slots, dtype=jnp.float32)[None, :]
    return jnp.any((at == j) & (k < n_doors), axis=0)


def _facade_boxes(s: _Solids, p, facade: str, length, origin, n_windows, lod: int) -> None:
    """Walls, openings, glass, frames and mullions of one facade, every floor at once.

    Local coordinates: ``a`` along the facade (centred), ``y`` up, ``d`` into the building from
    the wall plane. Arrays run over (floors, slots) at their largest counts; the front facade's
    ground floor has the entrances among its windows, and steps and canopies before them.
    """
    along, normal = (np.asarray(v, np.float32) for v in _FACADES[facade])
    up = np.array([0.0, 1.0, 0.0], np.float32)
    front = facade == "front"

    def put(part, a0, a1, y0, y1, d0, d1, valid):
        def world(a, y, d):
            a, y, d = jnp.broadcast_arrays(a, y, d)
            return origin + a[..., None] * along + y[..., None] * up - d[..., None] * normal

        s.boxes(part, world(a0, y0, d0), world(a1, y1, d1), valid)

    inset, half = p("window_inset"), 0.5 * length
    fh, g = p("floor_height"), p("ground_extra")
    n_slots = MAX_WINDOWS + (MAX_ENTRANCES if front else 0)
    f = jnp.arange(MAX_FLOORS, dtype=jnp.float32)[:, None]  # (F, 1)
    j = jnp.arange(n_slots, dtype=jnp.float32)[None, :]  # (1, S)
    ground = f == 0
    storey = f < p("floors")
    n_doors = p("entrances") if front else 0.0
    steps = p("steps") if front else 0.0
    n = jnp.where(ground, n_windows + n_doors, n_windows)  # openings per floor (F, 1)
    is_door = ground & _door_slots(n_windows + n_doors, n_doors, n_slots)[None, :]  # (F, S)
    opening = storey & (j < n)
    y_base = jnp.where(ground, 0.0, f * fh + g)
    y_top = (f + 1) * fh + g
    height = y_top - y_base
    margin = jnp.minimum(p("window_margin"), half - 0.5 * MIN_PIER)
    slot = (length - 2 * margin) / jnp.maximum(n, 1.0)
    centre = -half + margin + (j + 0.5) * slot
    scale = p("side_window_scale") if facade in ("left", "right") else 1.0
    scale = jnp.where(ground, scale * p("ground_window_scale"), scale)
    w = jnp.where(is_door, jnp.minimum(p("door_width"), slot - MIN_PIER),
                  jnp.minimum(p("window_width") * scale, slot - MIN_PIER))
    sill = p("window_sill")
    win_h = jnp.where(ground, p("ground_window_height"), p("window_height"))
    door_y0 = steps * p("step_height")
    y0 = jnp.where(is_door, door_y0, y_base + sill)
    y1 = jnp.where(is_door, door_y0 + jnp.minimum(p("door_height"), height - door_y0 - MIN_PIER),
                   y_base + sill + jnp.minimum(win_h, height - sill - MIN_PIER))
    a0, a1 = centre - 0.5 * w, centre + 0.5 * w
    # piers between openings (full storey; pier k ends at the facade's edge when k = n), then the
    # wall below and above each opening
    k = jnp.arange(n_slots + 1, dtype=jnp.float32)[None, :]
    edge = jnp.full((MAX_FLOORS, 1), half)
    pier_end = jnp.where(k == n, half, jnp.concatenate([a0, edge], 1))
    put(WALLS, jnp.concatenate([-edge, a1], 1), pier_end, y_base, y_top, 0.0, inset, storey & (k <= n))
    put(WALLS, a0, a1, y_base, y0, 0.0, inset, opening & (~is_door | (steps > 0)))
    put(WALLS, a0, a1, y1, y_top, 0.0, inset, opening)
    # the pane: at level 2 (no frames) as much of it as level 3's frames leave visible, so the
    # window masks of the two levels agree and the pane's edges lie inside the core wall's face
    # rather than along the reveal's (coplanar edges bias the silhouette renderer's gradients)
    fw = jnp.minimum(p("frame_width"), 0.25 * jnp.minimum(w, y1 - y0)) if lod == 2 else 0.0
    put(jnp.where(is_door, DOOR, WINDOWS), a0 + fw, a1 - fw, jnp.where(is_door, y0, y0 + fw), y1 - fw,
        inset - GLASS, inset, opening)
    win = opening & ~is_door
    if lod >= 3:
        fw, fd = p("frame_width"), p("frame_depth")
        back = inset - GLASS
        # frames wrap the opening's edges, so no frame face lies in a wall face
        yf = jnp.where(is_door, y0, y0 - fw)  # a door's frame stands on its threshold
        put(FRAMES, a0 - fw, a0 + fw, yf, y1 + fw, -fd, back, opening)
        put(FRAMES, a1 - fw, a1 + fw, yf, y1 + fw, -fd, back, opening)
        put(FRAMES, a0 - fw, a1 + fw, y1 - fw, y1 + fw, -fd, back, opening)
        put(FRAMES, a0 - fw, a1 + fw, y0 - fw, y0 + fw, -fd, back, win)
        mw, mid_a, mid_y = 0.5 * p("mullion_width"), 0.5 * (a0 + a1), 0.5 * (y0 + y1)
        put(FRAMES, mid_a - mw, mid_a + mw, y0, y1, back - 2 * GLASS, back, win & (p("window_split") >= 1))
        put(FRAMES, a0, a1, mid_y - mw, mid_y + mw, back - 2 * GLASS, back, win & (p("window_split") >= 2))
    if front:
        door = is_door[0] & opening[0]
        dl, dr, dt = a0[0], a1[0], y1[0]
        if lod >= 2:
            m = jnp.arange(MAX_STEPS, dtype=jnp.float32)[:, None]  # the lowest step reaches farthest out
            put(WALLS, dl - 0.02, dr + 0.02, 0.0, door_y0 - m * p("step_height"), -(m + 1) * p("step_depth"),
                inset, door & (m < steps))
        if lod >= 3:
            over = p("canopy_overhang")
            put(WALLS, dl - over, dr + over, dt + 0.02, dt + 0.035, -p("canopy_depth"), 0.0, door)


@GENERATORS.register("buildings")
class Buildings(Generator):
    """Houses and blocks: storeys of windows on four facades, entrances, balconies and a roof."""

    name = "buildings"
    spec = make_spec(_SPEC_ROWS)
    part_names = PARTS
    lods = (0, 1, 2, 3)
    reference_lod = 3
    shared_positions = True
    semantic_labels = BUILDING_LABELS
    part_semantic = tuple(BUILDING_LABELS[c] for c in ("wall", "window", "wall", "roof", "door", "wall"))
    """Frames and balconies count as wall: a window mask is the glass."""
    mask_class = "window"
    min_fit_lod = 2
    marker = ("door", "windows_front")
    """The class one facade alone carries, and that facade's count: the door tells the front from the
    back (``ipm.facades``)."""
    categorical = ("roof_type",)
    placements = tuple({"chimney": 1, "chimney_x": cx, "chimney_z": cz, "chimney_size": 0.1, "chimney_height": 0.2}
                       for cx in (-0.3, 0.0, 0.3) for cz in (-0.3, 0.0, 0.3))
    """The chimney, switched on and mid-sized, at nine places on the roof (``ipm.search.moves.place``)."""
    footprint = ("width", "depth")
    """The extent along the object's x and z axes (``ipm.search.moves.sight``)."""
    moves = ("read", "polish", "recentre", "roof", "sight", "place", "read again")
    """Counts read off the window masks, polish, re-centring, the roof race, the line-of-sight and the
    chimney sweeps (``ipm.search.moves``)."""
    ratios = ("side_window_scale", "ground_window_scale", "hip_ratio", "balcony_width", "chimney_x", "chimney_z")
    counts = ("floors", "windows_front", "windows_back", "windows_left", "windows_right")
    facing = {f"windows_{facade}": normal for facade, (_, normal) in _FACADES.items()}
    presets = {}  # filled below from named edits of the defaults

    def topology_key(self, x):
        return tuple(int(round(float(x[self.spec.index[n]]))) for n in DISCRETE)

    def _structure(self, key: tuple) -> dict:
        s = dict(zip(DISCRETE, key))
        s["balcony_floors"] = (list(range(1, s["floors"])) if s["balconies"] == 1 else
                               list(range(s["balcony_start"], s["floors"])) if s["balconies"] == 2 else [])
        return s

    def change_count(self, x, name, value):
        """A storey more or less keeps the walls' height (the floor height takes up the change,
        within its bounds); other counts change alone."""
        ix = self.spec.index
        walls = float(x[ix["floors"]] * x[ix["floor_height"]])
        x = np.array(x, np.float64)
        x[ix[name]] = value
        x = self.spec.clip(x)
        if name == "floors":
            x[ix["floor_height"]] = walls / x[ix["floors"]]
        return self.spec.clip(x)

    def quarter_turned(self, x):
        """``x`` with width and depth swapped: turned a quarter about +y, it covers what ``x`` covered."""
        out = np.array(x, np.float64)
        i, j = (self.spec.index[name] for name in self.footprint)
        out[i], out[j] = x[j], x[i]
        return self.spec.clip(out)

    def split_roof(self, x, share):
        """A pitched roof ``share`` of the height (walls, ground-floor extra and roof together),
        the storeys the rest: the floor height takes up the change, or a storey fewer or more
        where it would leave its bounds; the overhang at least a third of its range. One view of a
        low house shows where the eaves meet the walls only through a kink in the outline, so a fit
        that took a tall roof for walls (or walls for roof) stays there. None for a flat roof."""
        spec, ix = self.spec, self.spec.index
        if int(round(float(x[ix["roof_type"]]))) == FLAT:
            return None
        x = np.array(x, np.float64)
        floors, fh = x[ix["floors"]], x[ix["floor_height"]]
        total = _wall_top(lambda k: x[ix[k]]) + x[ix["roof_height"]]
        x[ix["roof_height"]] = share * total
        walls = max(total - x[ix["roof_height"]] - x[ix["ground_extra"]], 0.0)
        lo, hi = spec.lower[ix["floor_height"]], spec.upper[ix["floor_height"]]
        if not lo <= walls / floors <= hi:
            floors = np.round(walls / fh)
        x[ix["floors"]] = np.clip(floors, spec.lower[ix["floors"]], spec.upper[ix["floors"]])
        x[ix["floor_height"]] = walls / x[ix["floors"]]
        i = ix["roof_overhang"]
        x[i] = max(x[i], spec.lower[i] + (spec.upper[i] - spec.lower[i]) / 3)
        return spec.clip(x)

    def facades(self, x):
        """The four walls' outer faces up to the cornice (the facade boxes' planes)."""
        ix = self.spec.index
        hx, hz = 0.5 * x[ix["width"]], 0.5 * x[ix["depth"]]
        top = float(_wall_top(lambda k: x[ix[k]]))
        side = float(x[ix["depth"]] - 2 * x[ix["window_inset"]])
        spans = {"front": (float(x[ix["width"]]), (0.0, 0.0, hz)), "back": (float(x[ix["width"]]), (0.0, 0.0, -hz)),
                 "right": (side, (hx, 0.0, 0.0)), "left": (side, (-hx, 0.0, 0.0))}
        return {f"windows_{f}": (np.array(origin, float), np.array(_FACADES[f][0], float),
                                 np.array(_FACADES[f][1], float), length, top)
                for f, (length, origin) in spans.items()}

    def marker_extent(self, x):
        """The door's width and recess (the window inset)."""
        ix = self.spec.index
        return float(x[ix["door_width"]]), float(x[ix["window_inset"]])

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

    def _solids(self, x, lod: int) -> _Solids:
        """Every solid a building can have at ``lod``, at its largest count, with flags saying
        which ones the building ``x`` (jnp vector, discrete entries included) has."""
        ix = self.spec.index

        def p(name):
            return x[ix[name]]

        out = _Solids()
        w, d = p("width"), p("depth")
        hx, hz = 0.5 * w, 0.5 * d
        floors, roof_type = p("floors"), p("roof_type")
        flat = roof_type == FLAT
        top = _wall_top(p)
        inset = p("window_inset") if lod >= 2 else 0.0
        out.boxes(WALLS, jnp.stack([-hx + inset, 0.0, -hz + inset]), jnp.stack([hx - inset, top, hz - inset]))
        if lod >= 2:
            side = d - 2 * inset  # side facades run between the front and back walls
            for facade, length, origin in (("front", w, jnp.stack([0.0, 0.0, hz])),
                                           ("back", w, jnp.stack([0.0, 0.0, -hz])),
                                           ("right", side, jnp.stack([hx, 0.0, 0.0])),
                                           ("left", side, jnp.stack([-hx, 0.0, 0.0]))):
                _facade_boxes(out, p, facade, length, origin, p(f"windows_{facade}"), lod)
        if lod >= 1:
            co, ch = p("cornice_offset"), p("cornice_height")
            out.boxes(WALLS, jnp.stack([-hx - co, top - ch, -hz - co]), jnp.stack([hx + co, top, hz + co]))
            f = jnp.arange(1, MAX_FLOORS, dtype=jnp.float32)[:, None]  # storeys that may have a balcony
            has = (f < floors) & ((p("balconies") == 1) | ((p("balconies") == 2) & (f >= p("balcony_start"))))
            y = f * p("floor_height") + p("ground_extra")
            bw, bd = 0.5 * p("balcony_width") * w, p("balcony_depth")
            rh, zero = p("railing_height"), jnp.zeros_like(y)

            def corner(xc, yc, zc):
                return jnp.stack(jnp.broadcast_arrays(xc, yc, zc), -1)

            out.boxes(BALCONIES, corner(-bw, y - p("balcony_thickness"), hz - inset), corner(bw, y, hz + bd), has)
            if lod >= 3:
                out.boxes(BALCONIES, corner(-bw, y, hz + bd - RAIL), corner(bw, y + rh, hz + bd + zero), has)
                out.boxes(BALCONIES, corner(-bw, y, hz), corner(-bw + RAIL, y + rh, hz + bd - RAIL), has)
                out.boxes(BALCONIES, corner(bw - RAIL, y, hz), corner(bw, y + rh, hz + bd - RAIL), has)
        o = p("roof_overhang")
        ex, ez = hx + o, hz + o
        rt = p("roof_thickness")
        out.boxes(ROOF, jnp.stack([-ex, top, -ez]), jnp.stack([ex, top + rt, ez]), flat)
        if lod >= 2:
            r, ph = top + rt, top + rt + p("parapet_height")
            out.boxes(ROOF, jnp.stack([-ex, r, ez - RAIL]), jnp.stack([ex, ph, ez]), flat)
            out.boxes(ROOF, jnp.stack([-ex, r, -ez]), jnp.stack([ex, ph, -ez + RAIL]), flat)
            out.boxes(ROOF, jnp.stack([ex - RAIL, r, -ez + RAIL]), jnp.stack([ex, ph, ez - RAIL]), flat)
            out.boxes(ROOF, jnp.stack([-ex, r, -ez + RAIL]), jnp.stack([-ex + RAIL, ph, ez - RAIL]), flat)
        ridge = top + p("roof_height")
        half_ridge = jnp.where(roof_type == GABLE, ex, jnp.maximum(ex - p("hip_ratio") * ez, 0.01))
        out.prism(ROOF, jnp.stack([jnp.stack([-ex, top, -ez]), jnp.stack([ex, top, -ez]),
                                   jnp.stack([ex, top, ez]), jnp.stack([-ex, top, ez]),
                                   jnp.stack([-half_ridge, ridge, 0.0]), jnp.stack([half_ridge, ridge, 0.0])]),
                  ~flat)
        if lod >= 1:
            cx, cz, cs = p("chimney_x") * w, p("chimney_z") * d, 0.5 * p("chimney_size")
            peak = jnp.where(flat, top + rt, ridge) + p("chimney_height")
            out.boxes(ROOF, jnp.stack([cx - cs, top, cz - cs]), jnp.stack([cx + cs, peak, cz + cs]), p("chimney") == 1)
        return out

    @lru_cache(maxsize=None)
    def _layout_fn(self, lod):
        """Jitted x -> (part, present) of every solid at ``lod``, and the solids' kinds and counts."""
        kinds = []  # (kind, solids, vertices per solid), recorded while tracing (no compile, no execution)
        jax.eval_shape(lambda z: kinds.extend((k, *v.shape[:2]) for k, _, _, v in self._solids(z, lod).groups),
                       jnp.asarray(self.spec.default, jnp.float32))

        def layout(z):
            groups = self._solids(z, lod).groups
            return jnp.concatenate([g[1] for g in groups]), jnp.concatenate([g[2] for g in groups])

        return jax.jit(layout), kinds

    @lru_cache(maxsize=None)
    def _faces(self, lod):
        """Every solid's triangles at ``lod`` (indices into the positions) and triangles per solid."""
        faces, offset = [], 0
        for kind, n, k in self._layout_fn(lod)[1]:
            faces.append((_TEMPLATES[kind][None] + (offset + k * np.arange(n))[:, None, None]).reshape(-1, 3))
            offset += n * k
        per_solid = np.concatenate([np.full(n, len(_TEMPLATES[kind])) for kind, n, _ in self._layout_fn(lod)[1]])
        return np.concatenate(faces).astype(np.int64), per_solid

    def all_faces(self, lod):
        return self._faces(lod)[0]

    def vertex_layout(self, x, lod):
        layout, kinds = self._layout_fn(lod)
        parts, present = layout(x)
        per_solid = np.concatenate([np.full(n, k) for _, n, k in kinds])  # vertices per solid
        total = int(per_solid.sum())
        return (jnp.repeat(parts.astype(jnp.int32), per_solid, total_repeat_length=total),
                jnp.repeat(present.astype(bool), per_solid, total_repeat_length=total))

    @lru_cache(maxsize=None)
    def topology(self, key, lod):
        x = self.spec.default.copy()
        for name, v in zip(DISCRETE, key):
            x[self.spec.index[name]] = v
        parts, present = (np.asarray(a) for a in self._layout_fn(lod)[0](jnp.asarray(x, jnp.float32)))
        faces, per_solid = self._faces(lod)
        keep = np.repeat(present.astype(bool), per_solid)
        faces, labels = faces[keep], np.repeat(parts, per_solid)[keep]
        v = np.asarray(self.positions_fn(key, lod)(jnp.asarray(x, jnp.float32)), np.float64)
        fh = float(x[self.spec.index["floor_height"]])
        uv = np.stack([(v[:, 0] + v[:, 2]) / fh, v[:, 1] / fh], 1)  # one texture tile per storey
        return Topology(faces, labels.astype(np.int32), uv)

    def positions_fn(self, key, lod):
        """One function for every topology at ``lod`` (the solids at their largest counts; the
        topology's faces use those the building has): compiled once per level of detail."""
        return self._positions(lod)

    @lru_cache(maxsize=None)
    def _positions(self, lod):
        discrete = jnp.asarray(self.spec.discrete)

        def positions(x):
            x = jnp.where(discrete, jax.lax.stop_gradient(x), x)  # structure, not a direction to move in
            return jnp.concatenate([g[3].reshape(-1, 3) for g in self._solids(x, lod).groups]).astype(jnp.float32)

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
