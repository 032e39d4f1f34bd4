"""Buildings generator (the paper's third class, Figure 6): a main wing and up to three more
(the L, T and U plans and an annex), floors, window layouts, entrances, balconies and nine roof
kinds per wing, in four levels of detail.

Everything is built from closed solids whose corners are affine in the parameters (boxes, and a
ten-vertex solid for every pitched roof; ``solids``), so every part is watertight and the vertex
positions are a pure JAX function with a Jacobian; the discrete parameters (floors, windows per
facade, entrances, window split, roof kinds, balconies, chimney, steps, plan, annex, each wing's
storeys and windows) decide which solids exist. The wings' solids overlap the main wing's: the
renderer's depth test makes their union while fitting. The parameter table is ``table``; the body
over the footprint and the wings ``footprint``, the facades and their openings ``facades``, the
roofs ``roofs``; this module is the generator the search asks (its topology, positions, the
facades and counts its moves read, its presets).

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

from ipm.generators.base import GENERATORS, Generator, Topology
from ipm.generators.buildings.facades import FACADES, facade_boxes
from ipm.generators.buildings.footprint import core_solids, cornice_and_balconies, wing_solids
from ipm.generators.buildings.roofs import roof_solids
from ipm.generators.buildings.charts import charts
from ipm.generators.buildings.solids import TEMPLATES, Solids
from ipm.generators.buildings.table import (BALCONIES, DISCRETE, DOOR, FLAT, FRAMES, GABLE, GAMBREL, HALF_HIP, HIP,
                                            L_PLAN, MANSARD, PARTS, RECTANGLE, ROOF, ROOF_KINDS, ROOF_WEIGHTS,
                                            SALTBOX, SPEC, T_PLAN, U_PLAN,
                                            WALLS, WINDOWS, WINGS, wall_top, wing_top)
from ipm.io.semantic import BUILDING_LABELS

__all__ = ["Buildings", "PARTS", "WALLS", "WINDOWS", "FRAMES", "ROOF", "DOOR", "BALCONIES", "FLAT", "GABLE", "HIP"]


@GENERATORS.register("buildings")
class Buildings(Generator):
    """Houses and blocks: storeys of windows on four facades, entrances, balconies and a roof."""

    name = "buildings"
    spec = SPEC
    part_names = PARTS
    lods = (0, 1, 2, 3)
    reference_lod = 3
    shared_positions = True
    closed_solids = True
    semantic_labels = BUILDING_LABELS
    part_semantic = tuple(BUILDING_LABELS[c] for c in ("wall", "window", "wall", "roof", "door", "wall"))
    """Frames and balconies count as wall: a window mask is the glass."""
    mask_class = "window"
    min_fit_lod = 2
    marker = ("door", "windows_front")
    """The class one facade alone carries, and that facade's count: the door tells the front from the
    back (``ipm.facades``)."""
    categorical = ("roof_type",)
    plan_parameters = ("template",)
    """The plan: rectangle, L, T, U (``LoopSettings.plan_check``)."""
    placements = tuple({"chimney": 1, "chimney_x": cx, "chimney_z": cz, "chimney_size": 0.1, "chimney_height": 0.2}
                       for cx in (-0.3, 0.0, 0.3) for cz in (-0.3, 0.0, 0.3))
    """The chimney, switched on and mid-sized, at nine places on the roof (``ipm.search.moves.place``)."""
    footprint = ("width", "depth")
    """The extent along the object's x and z axes (``ipm.search.moves.sight``)."""
    moves = ("read", "polish", "recentre", "roof", "sight", "place", "read again")
    """Counts read off the window masks, polish, re-centring, the roof race, the line-of-sight and the
    chimney sweeps (``ipm.search.moves``)."""
    ratios = ("side_window_scale", "ground_window_scale", "hip_ratio", "knee_height", "knee_run", "ridge_offset",
              "balcony_width", "chimney_x", "chimney_z")
    counts = ("floors", "windows_front", "windows_back", "windows_left", "windows_right")
    facing = {f"windows_{facade}": normal for facade, (_, normal) in FACADES.items()}
    presets = {}  # filled below from named edits of the defaults

    def topology_key(self, x):
        return tuple(int(round(float(x[self.spec.index[n]]))) for n in DISCRETE)

    def _structure(self, key: tuple) -> dict:
        s = dict(zip(DISCRETE, key))
        s["balcony_floors"] = (list(range(1, s["floors"])) if s["balconies"] == 1 else
                               list(range(s["balcony_start"], s["floors"])) if s["balconies"] == 2 else [])
        on = (s["template"] >= L_PLAN, s["template"] == U_PLAN, s["annex"] == 1)
        s["wings"] = [k for k, wing_on in zip(WINGS, on) if wing_on]
        s["roofs"] = {s["roof_type"], *(s[f"wing{k}_roof"] for k in s["wings"])}
        return s

    def occam_parts(self, x) -> int:
        """The main wing and every wing the plan and the annex switch on."""
        return 1 + len(self._structure(self.topology_key(x))["wings"])

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
        total = wall_top(lambda k: x[ix[k]]) + x[ix["roof_height"]]
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
        top = float(wall_top(lambda k: x[ix[k]]))
        side = float(x[ix["depth"]] - 2 * x[ix["window_inset"]])
        spans = {"front": (float(x[ix["width"]]), (0.0, 0.0, hz)), "back": (float(x[ix["width"]]), (0.0, 0.0, -hz)),
                 "right": (side, (hx, 0.0, 0.0)), "left": (side, (-hx, 0.0, 0.0))}
        return {f"windows_{f}": (np.array(origin, float), np.array(FACADES[f][0], float),
                                 np.array(FACADES[f][1], float), length, top)
                for f, (length, origin) in spans.items()}

    def marker_extent(self, x):
        """The door's width, recess (the window inset) and height."""
        ix = self.spec.index
        return float(x[ix["door_width"]]), float(x[ix["window_inset"]]), float(x[ix["door_height"]])

    def sample(self, rng):
        """A random plausible building (the sampler of in-family cases), not a preset: footprint
        0.7-1.8 by 0.6-1.4, 1-6 storeys (fewer more likely), windows per facade from the facade's
        length and a spacing of 0.18-0.4 (a blank side wall with probability 1/3), 1-2 entrances,
        balconies on every storey or from one up with probability 1/2, a chimney on half the
        pitched roofs; the roof kind by OpenStreetMap's counts tempered by a square root
        (:data:`ROOF_WEIGHTS`), the plan a rectangle (0.4), an L (0.25), a T (0.15) or a U (0.2),
        an annex with probability 1/4; each wing as tall as the main wing or a storey lower (the
        annex any height up to it), of the main roof's kind with probability 0.6 and its pitch;
        every other parameter uniform over its range."""
        spec, ix = self.spec, self.spec.index
        x = spec.from_unit(rng.random(len(spec)))
        w, d = rng.uniform(0.7, 1.8), rng.uniform(0.6, 1.4)
        floors = int(rng.choice(np.arange(1, 7), p=np.array([3, 4, 3, 2, 1, 1]) / 14))
        spacing = rng.uniform(0.18, 0.4)
        roof = int(rng.choice(len(ROOF_KINDS), p=ROOF_WEIGHTS))
        values = {"width": w, "depth": d, "floors": floors, "floor_height": rng.uniform(0.28, 0.4),
                  "window_width": rng.uniform(0.08, 0.6 * spacing), "window_margin": rng.uniform(0.05, 0.15),
                  "entrances": int(rng.choice([1, 1, 2])), "roof_type": roof,
                  "balconies": int(rng.choice([0, 0, 1, 2])) if floors > 1 else 0,
                  "balcony_start": int(rng.integers(1, max(floors - 1, 1) + 1)), "steps": int(rng.integers(0, 3)),
                  "template": int(rng.choice(4, p=[0.4, 0.25, 0.15, 0.2])), "annex": int(rng.random() < 0.25)}
        for facade, length in (("front", w), ("back", w), ("left", d), ("right", d)):
            blank = facade in ("left", "right") and rng.random() < 1 / 3
            values[f"windows_{facade}"] = 0 if blank else int(np.clip(round(length / spacing), 1, 8))
        values["windows_front"] = max(values["windows_front"] - values["entrances"], 0)
        values["chimney"] = int(roof != FLAT and rng.random() < 0.5)
        pitch = x[ix["roof_height"]] / (0.5 * d)
        for k in WINGS:
            across = (min(0.45 * w, 1.2) if values["template"] == U_PLAN else min(0.8 * w, 1.2)) if k < 3 else 0.8 * d
            width, length = rng.uniform(0.3, max(across, 0.3)), rng.uniform(0.25, 0.9)
            wing_roof = roof if rng.random() < 0.6 else int(rng.choice(len(ROOF_KINDS), p=ROOF_WEIGHTS))
            values |= {f"wing{k}_width": width, f"wing{k}_length": length, f"wing{k}_shift": rng.uniform(-0.1, 0.1),
                       f"wing{k}_floors": int(rng.integers(max(floors - 1, 1), floors + 1)) if k < 3
                       else int(rng.integers(1, floors + 1)),
                       f"wing{k}_roof": wing_roof, f"wing{k}_roof_height": pitch * 0.5 * width * rng.uniform(0.8, 1.2),
                       f"wing{k}_windows": int(np.clip(round(length / spacing), 0, 8)),
                       f"wing{k}_end_windows": int(np.clip(round(width / spacing), 0, 8))}
        for name, v in values.items():
            x[ix[name]] = v
        return spec.clip(x)

    def active(self, x):
        """Parameters of parts the object does not have are inert (a flat roof's slope, an absent
        wing, a gambrel's knee on a house without one, ...)."""
        s = self._structure(self.topology_key(x))
        roofs, wings = s["roofs"], s["wings"]
        off = set()
        if s["roof_type"] == FLAT:
            off.add("roof_height")
        if FLAT not in roofs:
            off |= {"roof_thickness", "parapet_height"}
        if not roofs & {HIP, HALF_HIP, MANSARD}:
            off.add("hip_ratio")
        if not roofs & {GAMBREL, MANSARD}:
            off |= {"knee_height", "knee_run"}
        if SALTBOX not in roofs:
            off.add("ridge_offset")
        for k in WINGS:
            if k not in wings:
                off |= {name for name in self.spec.names if name.startswith(f"wing{k}_")}
            elif s[f"wing{k}_roof"] == FLAT:
                off.add(f"wing{k}_roof_height")
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

    def _solids(self, x, lod: int) -> Solids:
        """Every solid a building can have at ``lod``, at its largest count, with flags saying
        which ones the building ``x`` (jnp vector, discrete entries included) has."""
        ix = self.spec.index

        def p(name):
            return x[ix[name]]

        out = Solids()
        w, d = p("width"), p("depth")
        hx, hz = 0.5 * w, 0.5 * d
        top = wall_top(p)
        inset = p("window_inset") if lod >= 2 else 0.0
        core_solids(out, p, top, inset)
        if lod >= 2:
            side = d - 2 * inset  # side facades run between the front and back walls
            facade_boxes(out, p, "front", w, jnp.stack([0.0, 0.0, hz]), p("windows_front"), lod)
            others = ("back", "right", "left")  # no entrances: one set of arrays
            facade_boxes(out, p, others, jnp.stack([w, side, side]),
                         jnp.stack([jnp.stack([0.0, 0.0, -hz]), jnp.stack([hx, 0.0, 0.0]), jnp.stack([-hx, 0.0, 0.0])]),
                         jnp.stack([p(f"windows_{f}") for f in others]), lod)
        if lod >= 1:
            cornice_and_balconies(out, p, top, inset, lod)
        roof_solids(out, p, top, lod)
        wing_solids(out, p, inset, lod)
        return out

    def city_model(self, x, lod: int = 1):
        """The walls, cornice, roof and chimney of level ``lod`` joined into one solid per wing (the
        main wing's, then each wing's less what the earlier ones hold; balconies are installations,
        not the shell): CityJSON's LoD 2.0 from level 0, 2.2 from level 1, 3 from levels 2 and 3
        (windows and doors as their own surfaces in the facades' recesses, frames as wall);
        OpenStreetMap's roof shape, storeys and heights per wing, the main wing's for the building."""
        from ipm.io.cityjson import METRES_PER_UNIT, city_model

        x = self.spec.clip(x)
        ix = self.spec.index
        vertices = np.asarray(self.positions_fn(None, lod)(jnp.asarray(x, jnp.float32)), np.float64)
        roles = {WALLS: "wall", FRAMES: "wall", ROOF: "roof", WINDOWS: "window", DOOR: "door"}

        def faces_with(template, annex):  # the shell's faces with the wings these values switch on
            y = x.copy()
            y[ix["template"]], y[ix["annex"]] = template, annex
            topo = self.topology(self.topology_key(y), lod)
            keep = np.isin(topo.labels, list(roles))
            return {tuple(f): roles[k] for f, k in zip(topo.faces[keep].tolist(), topo.labels[keep])}

        def attributes(roof, floors, top, rise):
            shape = ROOF_KINDS[int(round(float(roof)))]
            return {"roofType": shape, "roof:shape": shape, "building:levels": int(round(float(floors))),
                    "roof:height": 0.0 if shape == "flat" else round(float(rise) * METRES_PER_UNIT, 3),
                    "height": round(float(top + rise) * METRES_PER_UNIT, 3)}

        def rise(roof, height):  # the roof over the walls' top
            return x[ix["roof_thickness"]] if int(round(float(roof))) == FLAT else height

        main = faces_with(RECTANGLE, 0)
        layers = [(main, attributes(x[ix["roof_type"]], x[ix["floors"]], wall_top(lambda k: x[ix[k]]),
                                    rise(x[ix["roof_type"]], x[ix["roof_height"]])))]
        # each wing's faces: those the plan and annex values with it have and the values before it lack
        with_and_without = {1: ((T_PLAN, 0), (RECTANGLE, 0)), 2: ((U_PLAN, 0), (T_PLAN, 0)),
                            3: ((RECTANGLE, 1), (RECTANGLE, 0))}
        for k in self._structure(self.topology_key(x))["wings"]:
            present, before = (faces_with(*values) for values in with_and_without[k])
            roof = x[ix[f"wing{k}_roof"]]
            layers.append(({f: r for f, r in present.items() if f not in before},
                           attributes(roof, x[ix[f"wing{k}_floors"]], wing_top(lambda n: x[ix[n]], k),
                                      rise(roof, x[ix[f"wing{k}_roof_height"]]))))
        parts = [(np.array(list(faces), np.int64).reshape(-1, 3), np.array(list(faces.values()), object), attrs)
                 for faces, attrs in layers]
        return city_model(vertices, parts, layers[0][1] | {"height": max(a["height"] for _, a in layers)},
                          lod={0: "2.0", 1: "2.2"}.get(lod, "3"))

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
            faces.append((TEMPLATES[kind][None] + (offset + k * np.arange(n))[:, None, None]).reshape(-1, 3))
            offset += n * k
        per_solid = np.concatenate([np.full(n, len(TEMPLATES[kind])) for kind, n, _ in self._layout_fn(lod)[1]])
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
    def _typical(self):
        """The median of 64 of the sampler's buildings (a fixed draw), parameter by parameter: the
        continuous values at which the texture charts take their shapes."""
        rng = np.random.default_rng(0)
        return np.median([self.sample(rng) for _ in range(64)], 0)

    @lru_cache(maxsize=None)
    def topology(self, key, lod):
        x = self.spec.default.copy()
        for name, v in zip(DISCRETE, key):
            x[self.spec.index[name]] = v
        parts, present = (np.asarray(a) for a in self._layout_fn(lod)[0](jnp.asarray(x, jnp.float32)))
        faces, per_solid = self._faces(lod)
        keep = np.repeat(present.astype(bool), per_solid)
        faces, labels = faces[keep], np.repeat(parts, per_solid)[keep]

        def uv():
            ref = np.where(self.spec.discrete, x, self._typical())  # the charts' shapes: a typical building's faces
            at = np.asarray(self.positions_fn(key, lod)(jnp.asarray(ref, jnp.float32)), np.float64)
            return charts(self._layout_fn(lod)[1], at, parts, present.astype(bool))

        n_positions = sum(n * k for _, n, k in self._layout_fn(lod)[1])  # every solid at its largest count
        return Topology(faces, labels.astype(np.int32), uv, n_positions)

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
