"""Traced JAX programs kept on disk between processes (``jax.export``), so a new process skips tracing them.

JAX's persistent compilation cache keeps compiled programs, but each process still traces and
lowers every program before it can look one up: for the JAX renderer's loss, 0.7-0.9 s of Python
and 0.3 s of lowering on this project's CPU machine, a dozen times per cup fit, most of a warm
fit's program starts. A :class:`StoredProgram` is a pure function of arrays whose program depends
on nothing but its source file(s), JAX's version and the argument shapes; those make the key of
its serialized StableHLO, kept beside the compilation cache (only where that cache is on). A
stored program gives the same numbers as the function traced afresh (``tests/test_render_edges.py``).
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
from functools import lru_cache
from pathlib import Path
from typing import Callable

import jax
import jaxlib
import numpy as np

from ipm.io.atomic import atomic_path

KEEP = 1024
"""Stored programs kept per folder; the least recently used go first beyond it."""


def program_folder() -> Path | None:
    """Where programs are stored: ``programs`` in JAX's persistent compilation cache folder (set by
    ``ipm.runtime.configure_threads``), or None when that cache is off (then nothing is stored:
    the compile would dominate anyway) or ``flatbuffers`` (JAX's serialization) is missing."""
    root = jax.config.jax_compilation_cache_dir
    if not root or importlib.util.find_spec("flatbuffers") is None:
        return None
    return Path(root) / "programs"


class StoredProgram:
    """``fn(*arrays)`` traced once per argument shapes and, where :func:`program_folder` is set,
    exported to disk under a key of ``sources`` (the files whose code it runs), JAX's, jaxlib's and
    numpy's versions, the backend, x64, ``name`` and the shapes; later processes load it instead of
    tracing.
    ``fn`` must close over nothing but what ``name`` spells out (sizes, budgets, settings).

    Call it eagerly (jitted) or from inside another function being traced (:meth:`inline`)."""

    def __init__(self, name: str, fn: Callable, sources: tuple[str, ...]):
        self.name, self.fn, self.sources = name, fn, tuple(sources)
        self._loaded: dict = {}
        self.jitted = jax.jit(self.inline)

    def __call__(self, *args):
        return self.jitted(*args)

    def inline(self, *args):
        """``fn(*args)``: the stored program's call where there is a folder, else ``fn`` itself."""
        folder = program_folder()
        if folder is None:
            return self.fn(*args)
        avals = [jax.typeof(a) for a in args]
        key = self._key(avals)
        if key not in self._loaded:
            self._loaded[key] = _load_or_export(folder / f"{key}.jaxexport", self.fn, avals)
        return self._loaded[key].call(*args)

    def _key(self, avals) -> str:
        h = hashlib.sha256(_source_hash(self.sources).encode())
        h.update(f"{jax.__version__} {np.__version__} {jax.default_backend()} {jax.config.jax_enable_x64}".encode())
        h.update(f"{self.name} {' '.join(str(a) for a in avals)}".encode())
        return h.hexdigest()[:40]


@lru_cache(maxsize=8)
def _source_hash(sources: tuple[str, ...]) -> str:
    """The hash of ``sources``, this file and jaxlib's version (what a stored program's code is)."""
    h = hashlib.sha256(jaxlib.__version__.encode())
    for source in (*sources, __file__):
        h.update(Path(source).read_bytes())
    return h.hexdigest()


def _load_or_export(path: Path, fn: Callable, avals):
    """The program in ``path``, or ``fn`` exported for ``avals`` and written there (atomically; a
    file that does not read back, half-written by a killed process or from another JAX, is
    replaced)."""
    from jax import export

    if path.exists():
        try:
            program = export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # noqa: BLE001 - any unreadable file is exported again
            program = None
        if program is not None:
            _touch(path)
            return program
    shapes = [jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type) for a in avals]
    program = export.export(jax.jit(fn))(*shapes)
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(program.serialize())
        _prune(path.parent)
    except OSError:  # a read-only or full folder: the program still runs, it is just not kept
        pass
    return program


def _prune(folder: Path, keep: int = KEEP) -> None:
    """Remove all but the ``keep`` most recently used programs in ``folder``."""
    files = list(folder.glob("*.jaxexport"))
    if len(files) <= keep:
        return

    def used(p: Path) -> float:
        try:
            return p.stat().st_mtime
        except OSError:  # removed by another process meanwhile
            return 0.0

    for old in sorted(files, key=used)[:-keep]:
        try:
            old.unlink()
        except OSError:
            pass


def _touch(path: Path) -> None:
    """Mark ``path`` used now (the pruning's order); a read-only folder is left as it is."""
    try:
        os.utime(path)
    except OSError:
        pass
