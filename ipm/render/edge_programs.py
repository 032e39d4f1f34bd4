"""The edge renderer's compiled programs (render, silhouette loss, class-mask loss, the generator's
pullback), one per image size, supersampling and budget, and how the budgets grow
(``ipm.render.edges``).
"""
from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ipm.render import edge_classes, edge_scan
from ipm.render.edge_classes import pyramid_loss, view_class_area
from ipm.render.edge_scan import view_area
from ipm.render.programs import StoredProgram
from ipm.render.silhouette import group_count as _group_count

SOURCES = (edge_scan.__file__, edge_classes.__file__, __file__)
"""The files whose code the programs run (their key when kept between processes)."""


def with_headroom(spans: int, grown: bool) -> int:
    """A span budget for meshes needing ``spans``, on first sight or after outgrowing the last. Each
    new budget is a new program to compile: about 2 s on a CPU, 8-10 s on an H100, where a loss
    costs about the same at any budget (4 ms from 64 to 512 px) while on a CPU the work grows with
    it. So a third (a quarter when grown) more on the CPU, and three times as many on a GPU
    (where a cup's reconstruction compiled one or two grown budgets a stage)."""
    if jax.default_backend() != "cpu":
        return 3 * int(spans)
    return int(spans * 1.25) if grown else int(spans) * 4 // 3


SMALL_IMAGE = 64
"""Images at most this many pixels wide and high take their budgets in powers of two (:func:`_round_up`)."""


def _round_up(n: int, small_image: bool) -> int:
    """``n`` rounded up to one of 8 sizes per octave (at most 12.5 % more work than asked for), or
    for a small image (:data:`SMALL_IMAGE`) to a power of two: each budget is a program to compile
    (2-4 s on a CPU) while a small image's loss costs a few milliseconds at any budget, so its
    programs are shared across meshes, seeds and processes. (At 96 px and above a loss's time
    grows with its budget: a building's fit at powers of two took 1.06 x as long, warm.)"""
    n = int(n)
    if small_image:
        return 1 << max(n - 1, 0).bit_length()
    step = max(1 << max(n.bit_length() - 4, 0), 1)
    return -(-n // step) * step


def _faces_key(faces: np.ndarray) -> tuple:
    """A key telling face arrays apart: their shape and a digest of every index (arrays padded to
    one size share their ends and differ inside)."""
    faces = np.ascontiguousarray(faces)
    return faces.shape, hashlib.blake2b(faces.tobytes(), digest_size=16).digest()


def _face_classes(faces, n_vertices: int = 0, blocks: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
    """One face array (F, 3) of G face groups (:func:`_group_count`) and, for more than one, each
    face's class (F,): its group's index (0: the silhouette's alone). With one vertex block per
    group (``blocks`` G) group g's indices move past the first g blocks of ``n_vertices``."""
    groups = [np.asarray(f, np.int32).reshape(-1, 3) for f in (faces if isinstance(faces, (list, tuple)) else [faces])]
    if _group_count(faces) == 1:
        return np.ascontiguousarray(groups[0]), None
    shift = int(n_vertices) if blocks == len(groups) else 0
    classes = np.concatenate([np.full(len(g), k) for k, g in enumerate(groups)]).astype(np.float32)
    return np.ascontiguousarray(np.concatenate([g + k * shift for k, g in enumerate(groups)])), classes


def padded(groups: np.ndarray, classes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces (F, 3) and their classes (F,) padded to the next power of two (at least 256) with
    triangles of no area (vertex 0 thrice, class 0, never drawn): meshes of similar size share
    one compiled program."""
    size = max(256, 1 << max(len(groups) - 1, 0).bit_length())
    pad = size - len(groups)
    return (np.concatenate([groups, np.zeros((pad, 3), groups.dtype)]),
            np.concatenate([classes, np.zeros(pad, classes.dtype)]))


def _class_sizes(classes: np.ndarray) -> tuple[int, ...]:
    """The number of faces of each class, a part of the keys of meshes with classes."""
    return tuple(int(c) for c in np.bincount(classes.astype(np.int64)))


@lru_cache(maxsize=64)
def _render_fn(width: int, height: int, ss: int, budget: int) -> StoredProgram:
    """(vertices, faces, w2c, focal, jitter) -> (pixel areas (n, H, W), spans needed per view)."""

    def fn(vertices, faces, w2c, focal, jitter):
        area, needed, _ = jax.vmap(lambda m, j: view_area(vertices, m, focal, faces, width, height, ss, j, budget))(
            w2c, jitter)
        return area, needed

    return _stored(fn, "render", width, height, ss, budget)


@lru_cache(maxsize=64)
def _class_render_fn(width: int, height: int, ss: int, budgets: tuple[int, int], n_classes: int = 1,
                     cull: bool = False) -> StoredProgram:
    """(vertices, faces, classes, w2c, focal, jitter) -> (pixel areas (n, H, W), the classes'
    visible areas (n, n_classes, H, W), spans and fragments needed per view (n, 2)); ``cull``:
    triangles facing away are not drawn (closed solids)."""

    def fn(vertices, faces, classes, w2c, focal, jitter):
        area, class_area, needed, _ = jax.vmap(lambda m, j: view_class_area(
            vertices, m, focal, faces, classes, width, height, ss, j, budgets, n_classes=n_classes, cull=cull))(
            w2c, jitter)
        return area, class_area, needed

    return _stored(fn, "class_render", width, height, ss, budgets, n_classes, *(("cull",) if cull else ()))


@lru_cache(maxsize=64)
def _loss_fn(program: Callable, name: str | None, width: int, height: int, ss: int, budget: int):
    """jit(z, constants, faces, targets, w2c, focal, jitter) -> (loss, d loss / d z, spans needed
    per view): the generator's vertices ``program(z, constants)`` (:func:`split`, its ``name``) and
    pullback around :func:`_silhouette_loss` in one program. The faces and the problem's constants
    are arguments, not constants (XLA would fold them into the program at every compilation, and a
    new case or camera would compile anew)."""
    render = _silhouette_loss(width, height, ss, budget)

    def fn(z, constants, faces, targets, w2c, focal, jitter):
        vertices, pullback = jax.vjp(lambda z: program(z, constants), z)
        loss, grad, needed = render.inline(vertices, faces, targets, w2c, focal, jitter)
        return loss, pullback(grad)[0], needed

    return _with_generator(fn, name, "silhouette_loss", width, height, ss, budget)


def split(vertex_fn: Callable) -> tuple[Callable, np.ndarray, str | None]:
    """``(program(z, constants), constants, name)`` of a vertex function: a ``BoundVertices``'s own
    (``ipm.problem``), or any other ``f(z)`` as a program that ignores its (empty) constants and
    has no name."""
    program = getattr(vertex_fn, "program", None)
    if program is not None:
        return program, vertex_fn.constants, vertex_fn.name
    return _ignoring_constants(vertex_fn), _NO_CONSTANTS, None


def _with_generator(fn: Callable, name: str | None, *settings) -> Callable:
    """``fn``, a program around the generator's vertex program ``name``, jitted; kept between
    processes where that program has a name (its code: the package's every module)."""
    return jax.jit(fn) if name is None else _stored(fn, name, *settings, sources=package_sources())


@lru_cache(maxsize=1)
def package_sources() -> tuple[str, ...]:
    """Every module of the ``ipm`` package: what a generator's vertex program may run."""
    return tuple(sorted(str(p) for p in Path(__file__).resolve().parents[1].rglob("*.py")))


_NO_CONSTANTS = np.zeros(0, np.float32)


@lru_cache(maxsize=64)
def _ignoring_constants(vertex_fn: Callable) -> Callable:
    return lambda z, constants: vertex_fn(z)


@lru_cache(maxsize=64)
def _silhouette_loss(width: int, height: int, ss: int, budget: int) -> StoredProgram:
    """(flattened vertices, faces, targets, w2c, focal, jitter) -> (loss, d loss / d vertices,
    spans needed per view)."""

    def surrogate(vertices, faces, targets, w2c, focal, jitter):
        vertices = vertices.reshape(-1, 3)
        n_views = len(targets)

        def view(m, target, j):
            area, needed, sur = view_area(vertices, m, focal, faces, width, height, ss, j, budget,
                                          lambda a: 2.0 * (a - target) / a.size / n_views)
            return jnp.mean((jax.lax.stop_gradient(area) - target) ** 2) / n_views, sur, needed

        loss, sur, needed = jax.vmap(view)(w2c, targets, jitter)
        return jnp.sum(sur), (jnp.sum(loss), needed)

    def fn(vertices, faces, targets, w2c, focal, jitter):
        (_, (loss, needed)), grad = jax.value_and_grad(surrogate, has_aux=True)(vertices, faces, targets, w2c,
                                                                                 focal, jitter)
        return loss, grad, needed

    return _stored(fn, "silhouette_loss", width, height, ss, budget)


@lru_cache(maxsize=64)
def _class_loss_fn(width: int, height: int, ss: int, budgets: tuple[int, int], highlight: tuple,
                   cull: bool = False) -> StoredProgram:
    """(vertices, faces, classes, targets, class_targets, w2c, focal, jitter) -> (loss, d loss /
    d vertices, spans and fragments needed per view (n, 2)) with the class-mask terms ``highlight``
    (a weight per class, pyramid levels, loss; class targets (n, K, H, W)). The generator is not in
    the program (a building's takes longer to compile than the renderer, and each resolution and
    budget is a program of its own): its vector-Jacobian product is compiled once (:func:`_pullback`).
    ``cull``: triangles facing away are not drawn (closed solids)."""
    weights, levels, kind = highlight

    def class_loss(class_area, class_target):
        return sum(weights[k] * pyramid_loss(class_area[k], class_target[k], levels, kind) for k in range(len(weights)))

    def surrogate(vertices, faces, classes, targets, class_targets, w2c, focal, jitter):
        n_views = len(targets)

        def view(m, target, class_target, j):
            def grads(a, c):
                return (2.0 * (a - target) / a.size / n_views,
                        jax.grad(lambda x: class_loss(x, class_target))(c) / n_views)

            area, class_area, needed, sur = view_class_area(vertices.reshape(-1, 3), m, focal, faces, classes, width,
                                                            height, ss, j, budgets, grads, n_classes=len(weights),
                                                            cull=cull)
            area, class_area = jax.lax.stop_gradient(area), jax.lax.stop_gradient(class_area)
            loss = jnp.mean((area - target) ** 2) + class_loss(class_area, class_target)
            return loss / n_views, sur, needed

        loss, sur, needed = jax.vmap(view)(w2c, targets, class_targets, jitter)
        return jnp.sum(sur), (jnp.sum(loss), needed)

    def fn(*args):
        (_, (loss, needed)), grad = jax.value_and_grad(surrogate, has_aux=True)(*args)
        return loss, grad, needed

    return _stored(fn, "class_loss", width, height, ss, budgets, highlight, *(("cull",) if cull else ()))


def _stored(fn: Callable, *name, sources: tuple[str, ...] = SOURCES) -> StoredProgram:
    """``fn``, a program of the edge renderer (the code of ``sources``) with the settings ``name``,
    kept between processes."""
    return StoredProgram(" ".join(map(str, name)), fn, sources)


@lru_cache(maxsize=64)
def _pullback(program: Callable, name: str | None = None):
    """jit(z, constants, d loss / d vertices) -> d loss / d z: the vector-Jacobian product of the
    generator's vertices ``program(z, constants)`` (:func:`split`, its ``name``)."""
    def fn(z, constants, cotangent):
        return jax.vjp(lambda z: program(z, constants), z)[1](cotangent)[0]

    return _with_generator(fn, name, "pullback")
