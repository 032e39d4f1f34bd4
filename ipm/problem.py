"""A reconstruction problem: a generator, the object pose, and the views to match.

The optimised vector is ``z = [u, pose]``: ``u`` the generator parameters in the unit cube,
``pose = (yaw, tilt_x, tilt_z, dx, dy, dz, log_scale)`` with angles in radians and the
translation and scale relative to an *anchor* estimated from the first view's mask (the
object stands on y = 0). All parts have similar step sizes, so one Adam rate serves.
World vertices are ``s * R_y(yaw) R_x(tilt_x) R_z(tilt_z) v + t`` with
``t = t0 + s0 * (dx, dy, dz)`` and ``s = s0 * exp(log_scale)``.
"""
from __future__ import annotations

from contextlib import contextmanager

import jax
import jax.numpy as jnp
import numpy as np

from ipm.errors import UserError
from ipm.generators.base import Generator, Mesh, build_mesh
from ipm.io.views import Views
from ipm.lanes import once
from ipm.render.cameras import pixel_ray

POSE_NAMES = ("yaw", "tilt_x", "tilt_z", "dx", "dy", "dz", "log_scale")
CAMERA_NAMES = ("pitch", "roll", "log_focal")
"""The genes of an unknown camera (``ipm.photo.UnknownCamera``), in ``z`` after the pose."""
POSE_LOWER = np.array([-np.inf, 0.0, 0.0, -1.5, 0.0, -1.5, -2.5])
POSE_UPPER = np.array([np.inf, 0.0, 0.0, 1.5, 0.0, 1.5, 2.5])
"""Pose bounds; the tilts' bounds are set per problem (``Problem(max_tilt=)``). ``dy`` is held at 0:
the object stands on y = 0 (``docs/design``, "Scene convention"; ``Problem(free_height=)`` where
the ground was estimated).
This prior is what resolves most of the single-view ambiguity
between distance along the ray and scale: with the base free to float 3 % of the height, a
workflow run ended 3 cm below the ground and 7 cm off along the ray (cup_1 IoU 0.83)."""


def foot_pixel(mask: np.ndarray) -> tuple[float, float]:
    """The pixel position (x, y) of a mask's foot: the middle of its lowest row, at that row's
    bottom edge (where the object meets the ground in front)."""
    bottom = int(np.nonzero(mask.max(1) > 0.5)[0].max())
    return float(np.nonzero(mask[bottom] > 0.5)[0].mean() + 0.5), bottom + 1.0


def estimate_anchor(views: Views) -> tuple[np.ndarray, float]:
    """Ground position (x, 0, z) and height of the object from the first view's mask.

    The lowest mask row is taken as the object's front contact with the ground plane y = 0;
    the highest row gives the height along the vertical through that point; the mask width just
    above the base gives the depth offset to the object's axis.
    """
    mask, c2w = views.masks[0], views.c2w[0]
    h, w = mask.shape
    foot_x, foot_y = foot_pixel(mask)
    bottom, top = int(foot_y) - 1, int(np.nonzero(mask.max(1) > 0.5)[0].min())
    origin, d = pixel_ray(foot_x, foot_y, c2w, views.fov_x, w, h)
    if d[1] > -1e-3:
        raise UserError("cannot place the object: the lowest mask pixel looks at or above the horizon "
                        "(the object must stand on the plane y = 0 below the camera)")
    contact = origin + d * (-origin[1] / d[1])
    # height: the top ray's closest approach to the vertical line through the contact point
    o2, d2 = pixel_ray(foot_x, float(top), c2w, views.fov_x, w, h)
    horiz = np.array([d2[0], 0.0, d2[2]])
    s = np.dot(contact - o2, horiz) / max(np.dot(horiz, horiz), 1e-9)
    height = float(o2[1] + s * d2[1])
    # width just above the base -> push the contact point back to the object's axis (the width at
    # mid height overshoots for vessels that widen upwards, such as bowls)
    low = bottom - max(1, int(round(0.1 * (bottom - top))))
    mcols = np.nonzero(mask[low] > 0.5)[0]
    dist = np.linalg.norm(contact - origin)
    f = 0.5 * w / np.tan(0.5 * views.fov_x)
    half_width = 0.5 * (mcols.max() - mcols.min() + 1) * dist / f
    back = contact - origin
    back[1] = 0.0
    back /= max(np.linalg.norm(back), 1e-9)
    centre = contact + back * half_width
    centre[1] = 0.0
    height = float(np.clip(height, 0.2 * half_width, 20.0 * max(half_width, 1e-3)))
    if not np.all(np.isfinite(centre)) or not np.isfinite(height) or height <= 0:
        raise UserError("cannot estimate the object's position from the input mask")
    return centre, height


def _rotation(yaw, tx, tz):
    cy, sy = jnp.cos(yaw), jnp.sin(yaw)
    cx, sx = jnp.cos(tx), jnp.sin(tx)
    cz, sz = jnp.cos(tz), jnp.sin(tz)
    ry = jnp.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = jnp.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    rz = jnp.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return ry @ rx @ rz


class Problem:
    """Generator + pose anchor; builds the pure JAX map z -> world vertices per topology.

    ``max_tilt`` bounds both tilt angles (radians); 0 holds the object upright. ``free_height``
    lets the object's foot leave y = 0 (by up to its height): for views whose ground was
    estimated, not given (``Views.ground_known``); only where several views fix the depth.
    ``camera``: an ``ipm.photo.UnknownCamera`` whose genes follow the pose in ``z``.
    """

    def __init__(self, generator: Generator, anchor_t: np.ndarray, anchor_s: float, max_tilt: float = 0.0,
                 free_height: bool = False, camera=None):
        self.generator = generator
        self.spec = generator.spec
        self.n_shape = len(self.spec)
        self.anchor_t = np.asarray(anchor_t, np.float64)
        self.anchor_s = float(anchor_s)
        self.camera = camera
        lower, upper = [np.zeros(self.n_shape), POSE_LOWER], [np.ones(self.n_shape), POSE_UPPER]
        if self.camera is not None:  # camera genes after the pose (``ipm.photo``)
            lower.append(self.camera.bounds()[0])
            upper.append(self.camera.bounds()[1])
        self.lower, self.upper = np.concatenate(lower), np.concatenate(upper)
        self.dim = len(self.lower)
        tilts = self.n_shape + np.array([POSE_NAMES.index("tilt_x"), POSE_NAMES.index("tilt_z")])
        self.lower[tilts], self.upper[tilts] = -max_tilt, max_tilt
        if free_height:
            dy = self.n_shape + POSE_NAMES.index("dy")
            self.lower[dy], self.upper[dy] = -1.0, 1.0
        groups = getattr(generator, "smooth_groups", ())
        self._smooth = [(np.arange(a, b), w, np.diff(np.eye(b - a), order, axis=0)) for a, b, w, order in groups]

    @classmethod
    def for_views(cls, generator: Generator, views: Views, max_tilt: float = 0.0) -> "Problem":
        """The problem of fitting ``generator`` to ``views``: the anchor from the first view; the
        foot free to leave y = 0 where the ground was estimated and several views fix depth; the
        camera's genes where it is unknown (``Views.camera``)."""
        return cls(generator, *estimate_anchor(views), max_tilt=max_tilt,
                   free_height=not views.ground_known and len(views) > 1, camera=views.camera)

    @property
    def fov_estimated(self) -> bool | None:
        """Whether an unknown camera's field of view is estimated too (False: given, a photo's
        Exif or ``--fov``); None for a known camera. The diff path's renderer, focal sweep and
        pitch starts are chosen by it."""
        return None if self.camera is None else not self.camera.fov_known

    def camera_gene(self, name: str) -> int:
        """Index in ``z`` of the unknown camera's gene ``name`` (:data:`CAMERA_NAMES`)."""
        return self.n_shape + len(POSE_NAMES) + CAMERA_NAMES.index(name)

    @contextmanager
    def holding(self, genes: dict[int, float]):
        """Within the block the genes ``genes`` (index -> value) are held at their values: their
        bounds close on them, so every ``clip`` (starts, Adam steps, mutations) keeps them there.
        The problem's compiled functions are kept (a copy of the problem would compile anew)."""
        saved = self.lower.copy(), self.upper.copy()
        try:
            for i, v in genes.items():
                self.lower[i] = self.upper[i] = v
            yield self
        finally:
            self.lower, self.upper = saved

    def key(self, z: np.ndarray) -> tuple:
        """Topology key (discrete parameter values) of ``z``."""
        return self.generator.topology_key(self.spec.from_unit(z[: self.n_shape]))

    def yaw_free(self, z: np.ndarray) -> bool:
        """True if the object ``z`` looks the same turned about its vertical axis
        (``Generator.yaw_symmetric``): its yaw is no part of its identity."""
        return self.generator.yaw_symmetric(self.spec.from_unit(z[: self.n_shape]))

    def recentred(self, z: np.ndarray) -> np.ndarray:
        """``z`` with its lengths and scale traded (every length times k, the scale over k: the
        same mesh) so that the lengths the object uses sit, in log terms, midway between the
        bounds they can reach together: one view fixes the product, not the share, and a fit that
        drifted to a small scale leaves its lengths no room to grow (a chimney at its largest
        size). ``z`` itself for a generator without the gauge (``Generator.ratios`` None)."""
        gen, spec, n = self.generator, self.spec, self.n_shape
        if gen.ratios is None:
            return z
        x = spec.from_unit(z[:n])
        lengths = ~spec.discrete & ~np.isin(spec.names, gen.ratios)
        used = lengths & gen.active(x) & (x != 0)
        if not used.any():
            return z
        lo, hi = length_room(x[used], spec.lower[used], spec.upper[used])
        lo, hi = lo.max(), hi.min()
        ls = n + POSE_NAMES.index("log_scale")
        log_k = float(np.clip(0.5 * (lo + hi) if lo <= hi else 0.0, z[ls] - self.upper[ls], z[ls] - self.lower[ls]))
        x[lengths] *= np.exp(log_k)
        out = np.array(z, np.float64)
        out[:n][lengths] = spec.to_unit(spec.clip(x))[lengths]
        out[ls] -= log_k
        return out

    def with_shape(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``z`` with its shape genes set to the parameters ``x`` (clipped into their bounds), projected
        (:meth:`clip`): how the sweeps and the count reading put edited parameters back."""
        out = np.array(z, np.float64)
        out[: self.n_shape] = self.spec.to_unit(self.spec.clip(x))
        return self.clip(out)

    def turned(self, z: np.ndarray, angle: float) -> np.ndarray:
        """``z`` with its yaw turned by ``angle`` radians about +y, projected (:meth:`clip`)."""
        out = np.array(z, np.float64)
        out[self.n_shape] += angle
        return self.clip(out)

    def clip(self, z: np.ndarray) -> np.ndarray:
        """Project ``z`` into bounds and its shape onto the generator's feasible objects
        (``Generator.feasible``); yaw is wrapped into [0, 2 pi)."""
        z = np.clip(np.asarray(z, np.float64), self.lower, self.upper)
        z[self.n_shape] = np.mod(z[self.n_shape], 2 * np.pi)
        spec, n = self.spec, self.n_shape
        x = spec.from_unit(z[:n])
        held = self.generator.feasible(x)
        if held is not x:  # only the entries it moved, so a feasible z comes back to the bit
            moved = held != x
            z[:n][moved] = spec.to_unit(held)[moved]
        return z

    def constants(self, dtype=np.float32) -> np.ndarray:
        """The problem's own numbers its vertex functions read as an argument, not as constants
        compiled in (:data:`CONSTANTS`), so problems of one generator share compiled programs."""
        cam = self.camera
        extra = [] if cam is None else [cam.pitch0, cam.fov0, *cam.foot]
        return np.array([*self.anchor_t, self.anchor_s, *extra], dtype)

    def vertex_fn(self, key: tuple, lod: int) -> BoundVertices:
        """Pure JAX function z (dim,) -> flattened world vertices (3 V,), for one topology (for a
        generator with ``shared_positions``, one function for all, reading the discrete values from z)."""
        return self._vertex_fn(None if self.generator.shared_positions else key, lod)

    @once
    def _vertex_fn(self, key: tuple | None, lod: int, render: bool = True) -> BoundVertices:
        return _bound(_vertex_program(self.generator, key, lod, self._camera_kind, render), self.constants())

    def _placement(self, z, xp=np):
        """The object's translation and scale at ``z`` (``xp``: numpy or jax.numpy): the anchor
        plus the pose's offsets, or, with an unknown camera, riding on its foot ray
        (``UnknownCamera.placement``)."""
        return _placement(z[self.n_shape:], self.constants(np.float64), self._camera_kind, xp)

    @property
    def _camera_kind(self):
        """The unknown camera's class (``ipm.photo.UnknownCamera``), whose ``of`` makes one from
        :meth:`constants` inside a program; None for a known camera."""
        return None if self.camera is None else type(self.camera)

    @once
    def group_vertex_fn(self, lod: int, groups: tuple[tuple[int, ...], ...]) -> BoundVertices:
        """For a generator with ``shared_positions``: pure JAX z -> world vertices of every render
        group, flattened (G * 3 V,). Group g keeps the vertices of the solids the object ``z`` has
        whose part is in ``groups[g]``; every other vertex goes to the object's ground point, so
        its triangles have no area. With ``generator.all_faces(lod)`` in every group, one renderer
        scene serves all topologies (a new Mitsuba scene costs seconds of kernel compilation)."""
        return _bound(_group_program(self.generator, lod, groups, self._camera_kind), self.constants())

    def regulariser(self, z: np.ndarray, weight: float) -> tuple[float, np.ndarray]:
        """Smoothness prior on the generator's control sequences: mean squared finite differences
        of each group's order (``generator.smooth_groups``)."""
        grad = np.zeros_like(z)
        value = 0.0
        for idx, w, diff in self._smooth:
            d = diff @ z[idx]
            value += weight * w * np.mean(d**2)
            grad[idx] += 2 * weight * w / len(d) * (diff.T @ d)
        return value, grad

    def world_mesh(self, z: np.ndarray, lod: int) -> Mesh:
        """The generated mesh in the world frame (numpy)."""
        key = self.key(z)
        topo = self.generator.topology(key, lod)
        fn = self._vertex_fn(None if self.generator.shared_positions else key, lod, render=False)
        verts = np.asarray(fn(np.asarray(z, np.float32)), np.float64).reshape(-1, 3)
        return build_mesh(verts, topo, self.generator.part_names)

    def object_height(self, u: np.ndarray) -> float:
        """Height of the generated object in its own frame (for the initial scale)."""
        x = self.spec.from_unit(u)
        key = self.generator.topology_key(x)
        lod = min(self.generator.lods)
        v = np.asarray(self.generator.positions_fn(key, lod)(jnp.asarray(x, jnp.float32)))
        v = v[np.unique(self.generator.topology(key, lod).faces)]
        return float(max(v[:, 1].max() - v[:, 1].min(), 1e-3))

    def initial_z(self, u: np.ndarray, yaw: float, camera: np.ndarray | None = None) -> np.ndarray:
        """``z`` for unit parameters ``u`` at ``yaw``, scaled so its height matches the anchor; with
        an unknown camera, seen by the camera genes ``camera`` (default: the render camera's)."""
        pose = np.array([yaw, 0.0, 0.0, 0.0, 0.0, 0.0, -np.log(self.object_height(u))])
        if self.camera is None:
            return self.clip(np.concatenate([u, pose]))
        genes = np.array([self.camera.pitch0, 0.0, 0.0]) if camera is None else camera
        return self.clip(np.concatenate([u, pose, genes]))

    def to_world(self, z: np.ndarray):
        """The map of object-frame points (k, 3) to the world at ``z``'s pose (numpy); with an
        unknown camera, the render camera's world (where ``views.c2w`` sees them). The pose is
        worked out once, so each call of the map is a few operations."""
        world, pose = _world_maps(self.n_shape, self._camera_kind, True)
        zj, c = jnp.asarray(z, jnp.float32), jnp.asarray(self.constants())
        posed = pose(zj, c)
        return lambda v: np.asarray(world(jnp.asarray(v, jnp.float32), zj, c, posed), np.float64)

    def decode(self, z: np.ndarray) -> dict:
        """Parameters by name and the pose in world terms (for params.json)."""
        n = self.n_shape
        p = z[n:]
        camera = {} if self.camera is None else {"camera": self.camera.describe(p[len(POSE_NAMES):])}
        translation, scale = self._placement(np.asarray(z, np.float64))
        return {
            **camera,
            "generator": self.generator.name,
            "params": self.spec.as_dict(self.spec.from_unit(z[:n])),
            "pose": {
                "yaw": float(p[0]), "tilt_x": float(p[1]), "tilt_z": float(p[2]),
                "translation": np.asarray(translation).tolist(), "scale": float(scale),
            },
        }


CONSTANTS = ("anchor_x", "anchor_y", "anchor_z", "anchor_scale", "pitch0", "fov0", "foot_x", "foot_y", "width",
             "height")
"""The numbers of :meth:`Problem.constants`: the anchor, then an unknown camera's (``ipm.photo.UnknownCamera``)."""


class BoundVertices:
    """A vertex program ``program(z, constants)`` shared by every problem of one generator, topology
    and level of detail, bound to one problem's :meth:`Problem.constants`: called as ``f(z)``. The
    renderers compile ``program`` with the constants as an argument (``ipm.render.edge_programs``),
    so a second case, seed, field of view or pitch start reads the compiled loss back. ``name``
    spells out what, beside the package's source, fixes the program (a renderer keeps the programs
    built on it between processes: ``ipm.render.programs``)."""

    def __init__(self, program, constants: np.ndarray, name: str | None = None):
        self.program, self.constants, self.name = program, constants, name

    def __call__(self, z):
        return self.program(z, self.constants)


_PROGRAMS: dict = {}
"""Vertex programs by (generator class, topology or groups, level of detail, camera, render)."""


def _bound(name: tuple, constants: np.ndarray) -> BoundVertices:
    """The vertex program ``_PROGRAMS[name]`` bound to ``constants``, with ``name`` spelt out."""
    def spell(v):
        return f"{v.__module__}.{v.__qualname__}" if isinstance(v, type) else repr(v)

    return BoundVertices(_PROGRAMS[name], constants, " ".join(spell(v) for v in name))


def length_room(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The log factors (least, most) by which each length ``x`` (non-zero; a signed one, such as a
    wing's shift along its side, moves towards its bound of its own sign) can be scaled within
    its bounds; -inf where no bound limits the shrinking."""
    far, near = np.where(x > 0, upper, lower) / x, np.where(x > 0, lower, upper) / x
    with np.errstate(divide="ignore"):
        return np.where(near > 0, np.log(np.maximum(near, 1e-300)), -np.inf), np.log(far)


def _vertex_program(gen: Generator, key: tuple | None, lod: int, camera, render: bool = True) -> tuple:
    """The name in ``_PROGRAMS`` of jit(z, constants) -> flattened vertices of ``gen``'s topology
    ``key`` at ``lod``."""
    name = (type(gen), "topology", key, lod, camera, render)
    if name not in _PROGRAMS:
        positions = gen.positions_fn(key, lod)
        shape_x, world = _maps(gen, key, camera, render)

        def fn(z, c):
            return world(positions(shape_x(z)), z, c).ravel()

        _PROGRAMS[name] = jax.jit(fn)
    return name


def _group_program(gen: Generator, lod: int, groups: tuple[tuple[int, ...], ...], camera) -> tuple:
    """The name in ``_PROGRAMS`` of jit(z, constants) -> vertices of every render group
    (:meth:`Problem.group_vertex_fn`)."""
    name = (type(gen), "groups", groups, lod, camera, True)
    if name not in _PROGRAMS:
        positions = gen.positions_fn(None, lod)
        shape_x, world = _maps(gen, None, camera, True)
        members = [jnp.asarray(np.isin(np.arange(len(gen.part_names)), g)) for g in groups]

        def fn(z, c):
            x = shape_x(z)
            part, present = gen.vertex_layout(x, lod)
            v = world(positions(x), z, c)
            ground = world(jnp.zeros((1, 3), v.dtype), z, c)
            return jnp.concatenate([jnp.where((present & m[part])[:, None], v, ground) for m in members]).ravel()

        _PROGRAMS[name] = jax.jit(fn)
    return name


def _maps(gen: Generator, key: tuple | None, camera, render: bool):
    """``shape_x(z)``: physical parameters (discrete ones from ``key``, or rounded from ``z`` when
    ``key`` is None); ``world(v, z, constants)``: generator-frame vertices (V, 3) to the world, and
    with an unknown camera (``camera``: its class, ``Problem._camera_kind``) and ``render`` on to the
    render camera's frame (``ipm.photo``)."""
    spec, n = gen.spec, len(gen.spec)
    lo, span = jnp.asarray(spec.lower, jnp.float32), jnp.asarray(spec.upper - spec.lower, jnp.float32)
    discrete = jnp.asarray(spec.discrete)
    disc_values = np.array(spec.default, np.float32)
    for name, value in zip([nm for nm, d in zip(spec.names, spec.discrete) if d], key or ()):
        disc_values[spec.index[name]] = value
    disc_values = jnp.asarray(disc_values)

    def shape_x(z):
        x = lo + jnp.clip(z[:n], 0.0, 1.0) * span
        return jnp.where(discrete, jnp.round(x) if key is None else disc_values, x)

    return shape_x, _world_maps(n, camera, render)[0]


def _world_maps(n: int, camera, render: bool):
    """:func:`_maps`' ``world(v, z, constants, posed=None)`` for ``n`` shape genes, and
    ``pose(z, constants)``, the ``posed`` that ``world`` otherwise works out on each call (traced,
    the same operations in the same order as ever, so the compiled programs stay those cached)."""

    def placed(z, c):
        p = z[n:]
        return (p, *_placement(p, c, camera, jnp))

    def pose(z, c):
        p, t, s = placed(z, c)
        return p, t, s, _rotation(p[0], p[1], p[2])

    def world(v, z, c, posed=None):
        p, t, s = placed(z, c) if posed is None else posed[:3]
        scaled = s * v
        out = scaled @ (_rotation(p[0], p[1], p[2]) if posed is None else posed[3]).T + t
        return camera.of(c[4:]).to_render(out, p[len(POSE_NAMES):]) if camera is not None and render else out

    return world, pose


def _placement(p, c, camera, xp=np):
    """Translation and scale of the pose genes ``p`` (then the camera's) for the constants ``c``
    (:data:`CONSTANTS`; ``camera``: an unknown camera's class or None; ``xp``: numpy or jax.numpy)."""
    t0, s0 = xp.asarray(c[:3], p.dtype), c[3]
    if camera is None:
        return t0 + s0 * p[3:6], s0 * xp.exp(p[6])
    here, base, ratio = camera.of(c[4:]).placement(p[len(POSE_NAMES):], xp)
    return here + ratio * (t0 - base + s0 * p[3:6]), s0 * xp.exp(p[6]) * ratio
