"""What every procedural generator provides: a parameter spec, presets, and a pure JAX mesh function.

A generator's mesh topology (faces, part labels, UVs) depends only on its discrete
parameters and the level of detail; vertex positions are a pure, jittable JAX function
of the full parameter vector, so ``jax.jacfwd`` gives dpos/dP (zero for discrete entries).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Sequence

import numpy as np

from ipm.errors import UserError
from ipm.registry import Registry

GENERATORS: Registry = Registry("generator")
"""Procedural generators by name (``GENERATORS["dishes"]`` is a class); filled by ``ipm.generators``."""


@dataclass(frozen=True)
class ParamSpec:
    """Names, bounds, discreteness and defaults of a generator's parameters (physical units)."""

    names: tuple[str, ...]
    """Parameter names, in vector order."""
    lower: np.ndarray
    """Lower bounds, shape (n,)."""
    upper: np.ndarray
    """Upper bounds, shape (n,)."""
    discrete: np.ndarray
    """True for integer-valued parameters (their derivative is zero), shape (n,)."""
    default: np.ndarray
    """Default values, shape (n,)."""

    def __len__(self) -> int:
        return len(self.names)

    @cached_property
    def index(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.names)}

    @cached_property
    def levels(self) -> np.ndarray:
        """Number of values of each discrete parameter, 0 for continuous ones, shape (n,)."""
        return np.where(self.discrete, np.round(self.upper - self.lower).astype(int) + 1, 0)

    def to_unit(self, x: np.ndarray) -> np.ndarray:
        """Map physical values to the unit cube that optimisers work in."""
        return (np.asarray(x, np.float64) - self.lower) / (self.upper - self.lower)

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Map unit-cube values back to physical values, rounding discrete entries."""
        u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
        x = self.lower + u * (self.upper - self.lower)
        return np.where(self.discrete, np.round(x), x)

    def clip(self, x: np.ndarray) -> np.ndarray:
        """Clip physical values into bounds and round discrete entries."""
        x = np.clip(np.asarray(x, np.float64), self.lower, self.upper)
        return np.where(self.discrete, np.round(x), x)

    def as_dict(self, x: np.ndarray) -> dict[str, float]:
        """Parameter values by name (discrete ones as ints)."""
        return {n: (int(round(v)) if d else float(v)) for n, v, d in zip(self.names, x, self.discrete)}

    def from_dict(self, values: dict[str, float], base: np.ndarray | None = None) -> np.ndarray:
        """A vector from ``base`` (default: defaults) with named entries replaced; unknown names fail."""
        x = np.array(self.default if base is None else base, np.float64)
        for name, v in values.items():
            if name not in self.index:
                raise UserError(f"unknown parameter {name!r}")
            v = float(v)
            if not np.isfinite(v):
                raise UserError(f"parameter {name!r} is not finite")
            x[self.index[name]] = v
        return x


def make_spec(entries: Sequence[tuple[str, float, float, bool, float]]) -> ParamSpec:
    """Build a spec from ``(name, lower, upper, discrete, default)`` rows."""
    names, lo, hi, disc, dflt = zip(*entries)
    return ParamSpec(tuple(names), np.array(lo, float), np.array(hi, float),
                     np.array(disc, bool), np.array(dflt, float))


@dataclass(frozen=True)
class Topology:
    """The parts of a mesh that do not move with continuous parameters."""

    faces: np.ndarray
    """Triangle vertex indices, shape (F, 3), counter-clockwise seen from outside."""
    labels: np.ndarray
    """Part label per triangle, shape (F,), indexing the generator's ``part_names``."""
    charts: Callable[[], np.ndarray] = field(repr=False, compare=False)
    """Computes :attr:`uv` when first asked: a search meets many topologies and writes one mesh."""
    n_vertices: int
    """How many positions the topology's faces index."""

    @cached_property
    def uv(self) -> np.ndarray:
        """Texture coordinates per triangle corner, shape (F, 3, 2): each part's charts in [0, 1]^2
        (``ipm.uv``), a seam splitting a vertex's UV without splitting the vertex."""
        return self.charts()


@dataclass
class Mesh:
    """A generated mesh with everything a user needs to edit or render it."""

    vertices: np.ndarray
    """Positions, shape (V, 3)."""
    faces: np.ndarray
    """Triangles, shape (F, 3)."""
    normals: np.ndarray
    """Unit vertex normals, shape (V, 3)."""
    uv: np.ndarray | None
    """Texture coordinates per triangle corner, shape (F, 3, 2); None only where a search asked
    for a mesh without them."""
    labels: np.ndarray
    """Part label per triangle, shape (F,)."""
    part_names: tuple[str, ...]
    """Names of the part labels."""


SEEN_COS = float(np.cos(np.radians(75.0)))
"""A side of an object counts as seen by a view when its outward normal is within 75 degrees of
the direction to the camera (at grazing angles its windows merge in the image)."""


class Generator:
    """Base class: subclasses set ``name``, ``spec``, ``part_names``, ``presets``, ``lods``
    and implement ``topology_key``, ``topology`` and ``positions_fn``."""

    name: str
    spec: ParamSpec
    part_names: tuple[str, ...]
    presets: dict[str, np.ndarray]
    lods: tuple[int, ...] = (0, 1, 2)
    reference_lod: int = 2
    """Level of detail of the synthetic references (the generator's full detail)."""
    differentiable: bool = True
    """False for generators without a JAX positions function (searched by the GA path only)."""
    plant: bool = False
    """True for a generator of plants, whose parts are branches and foliage: the GA path fits it
    with the tree loss (``ipm.losses.tree``) and estimates its anchor from the trunk's foot."""
    shared_positions: bool = False
    """True when ``positions_fn`` is one function for every topology of a level of detail (it reads
    the discrete values from the vector; each topology's faces use the vertices it has), so an
    optimiser compiles it once per level rather than once per topology. Such a generator also
    implements ``all_faces`` and ``vertex_layout``, so a renderer keeps one scene for all topologies."""
    semantic_labels: dict[str, int] | None = None
    """Label map of the class's semantic images (``ipm.io.semantic``), None if it has none."""
    part_semantic: tuple[int, ...] = ()
    """The semantic label of each part (with ``semantic_labels``)."""
    mask_class: str | None = None
    """Semantic class whose mask the differentiable path matches beside the silhouette (buildings:
    window), weighted by the profile's ``window_weight``; None: silhouette only."""
    min_fit_lod: int = 0
    """Lowest level of detail the differentiable path searches at (the first that has the
    ``mask_class`` parts: buildings' windows appear at level 2)."""
    counts: tuple[str, ...] = ()
    """Discrete parameters that count what a person checks in a result (storeys, windows per
    facade): parameter recovery reports whether they came back exactly (``ipm.metrics.recovery``)."""
    facing: dict[str, tuple[float, float, float]] = {}
    """Count parameters that shape one side of the object only, with that side's outward normal
    in the object frame: they are scored only where the input view sees that side."""
    categorical: tuple[str, ...] = ()
    """Discrete parameters whose values are kinds, not amounts (buildings: the roof type): polish
    tries every other value, not the next ones (``ipm.search.moves.polish``), and the roof race
    every value (``ipm.search.moves.roof``): one kind's basin is not next to another's."""
    closed_solids: bool = False
    """True when every mesh is a union of closed, outward-facing solids: a renderer may then draw
    the triangles facing the camera alone (``ipm.render.edges``)."""
    sided_part: str | None = None
    """A part set off the vertical axis whose side and turn one view's outline cannot tell (a cup's
    handle in front of the body or behind it): the ``handle side`` move tries its mirror and turns
    and asks the colour image's shading (``ipm.search.moves.handle``)."""
    ratios: tuple[str, ...] | None = None
    """The continuous parameters that are not lengths (fractions, scale factors): every other
    continuous one is a length, so lengths times k at scale 1 / k make the same mesh, a gauge
    the differentiable path re-centres (:meth:`ipm.problem.Problem.recentred`). None: the
    generator has no such gauge (a length that is fixed, such as a normalised height)."""
    moves: tuple[str, ...] = ("polish",)
    """The moves of the differentiable search this generator wants, by name (``ipm.search.moves``;
    a move's module says what else it asks of the generator)."""
    plan_parameters: tuple[str, ...] = ()
    """Discrete parameters that make the object's plan (a building's wings): where the learned start's
    fit of the input view is poor, its other values get a stage of their own (``LoopSettings.plan_check``)."""
    distance_ignores: tuple[str, ...] = ()
    """Parameters left out of :func:`ipm.cases.unit_distance` (a random stream's seed: any two
    seeds are far apart in the unit cube, yet they do not make a different kind of object)."""

    def occam_parts(self, x: np.ndarray) -> int:
        """How many parts of the kind one view may show where there are none (a building's wings)
        object ``x`` has: the choice between finalists prefers fewer (``ipm.search.loop``).
        Default: 0, no such parts."""
        return 0

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """A random object of the generator's family (physical parameters), for the test split's
        in-family cases (``ipm.cases``). Default: uniform in the unit cube."""
        return self.spec.from_unit(rng.random(len(self.spec)))

    def feasible(self, x: np.ndarray) -> np.ndarray:
        """The nearest object ``x`` (physical values in bounds) that the generator builds as intended,
        ``x`` itself where it is one; the search projects every candidate onto it
        (``ipm.problem.Problem.clip``). Default: every ``x`` in bounds."""
        return x

    def active(self, x: np.ndarray) -> np.ndarray:
        """Mask (n,) of the parameters that shape the object ``x``; the others are inert for it
        (a handle's parameters when it has none). Default: all of them."""
        return np.ones(len(self.spec), bool)

    def yaw_symmetric(self, x: np.ndarray) -> bool:
        """True if the object ``x`` looks the same turned about its vertical axis (a yaw error
        means nothing for it). Default: False."""
        return False

    def texture_symmetry(self, part: int, res: int) -> np.ndarray | None:
        """Texels of part ``part``'s ``res`` square texture grouped so that a group's texels look
        alike (``ipm.texture.fill`` fills an unseen texel from its group), -1 for none; None where
        the generator knows no symmetry. Default: None."""
        return None

    def seen_counts(self, yaw: float, to_cameras) -> list[str]:
        """The count parameters (:attr:`counts`) that views from the world directions
        ``to_cameras`` (k, 3) show of the object turned by ``yaw`` about +y: all but the
        :attr:`facing` ones whose side faces away from every camera (one view sees at most two
        facades of a house; the windows on the others cannot be read from it)."""
        from ipm.pose import yaw_matrix

        rot = yaw_matrix(yaw)  # as ipm.problem and ipm.synth turn objects
        d = np.atleast_2d(np.asarray(to_cameras, np.float64))
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        return [n for n in self.counts
                if n not in self.facing or (d @ (rot @ np.asarray(self.facing[n]))).max() > SEEN_COS]

    def city_model(self, x: np.ndarray, lod: int = 1) -> dict | None:
        """The object ``x`` at level of detail ``lod`` as a CityJSON 2.0 document
        (``ipm.io.cityjson``), for generators of things city models hold (buildings); None for the
        others (the default)."""
        return None

    def topology_key(self, x: np.ndarray) -> tuple:
        """The discrete parameter values that decide the topology."""
        raise NotImplementedError

    def topology(self, key: tuple, lod: int) -> Topology:
        raise NotImplementedError

    def positions_fn(self, key: tuple, lod: int) -> Callable:
        """A pure JAX function: physical parameter vector (n,) -> vertex positions (V, 3)."""
        raise NotImplementedError

    def all_faces(self, lod: int) -> np.ndarray:
        """(shared_positions) Every triangle a topology of ``lod`` may have, as indices into the
        positions: a topology's faces are a subset of these."""
        raise NotImplementedError

    def vertex_layout(self, x, lod: int):
        """(shared_positions) JAX: part label (V,) and presence flag (V,) of every vertex for the
        physical parameter vector ``x`` (discrete entries included); absent vertices belong to
        solids this object does not have."""
        raise NotImplementedError

    def mesh(self, x: np.ndarray, lod: int = 1, uv: bool = True) -> Mesh:
        """Generate the mesh for physical parameters ``x`` (numpy in, numpy out); ``uv=False``
        leaves out the texture coordinates (a mesh only rendered as a silhouette)."""
        import jax.numpy as jnp

        x = self.spec.clip(x)
        key = self.topology_key(x)
        topo = self.topology(key, lod)
        verts = self.positions_fn(key, lod)(jnp.asarray(x, jnp.float32))
        return build_mesh(np.asarray(verts, np.float64), topo, self.part_names, uv)


def build_mesh(vertices: np.ndarray, topo: Topology, part_names: tuple[str, ...], uv: bool = True) -> Mesh:
    """A :class:`Mesh` of ``topo`` at ``vertices`` with normals, keeping only the vertices its faces
    use (``uv=False``: without the topology's texture coordinates, which a topology that makes
    them on first read then never makes)."""
    used = np.unique(topo.faces)
    if len(used) < len(vertices):
        remap = np.full(len(vertices), -1, np.int64)
        remap[used] = np.arange(len(used))
        vertices, faces = vertices[used], remap[topo.faces]
    else:
        faces = topo.faces
    return Mesh(vertices, faces, vertex_normals(vertices, faces), topo.uv if uv else None, topo.labels, part_names)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals."""
    fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
