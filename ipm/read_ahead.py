"""Compiled programs read ahead from JAX's persistent compilation cache while a run starts.

A warm fit reads a hundred programs back from the cache, each when it is first called: a
building's 110 took 5.7 s of a 58 s fit, a cup's 54 took 2.7 s of 22 s (faster kind, 2 threads),
nearly all of it XLA rebuilding the executable, which releases the GIL. :func:`read_ahead` keeps,
per name (a method and a generator), the cache keys the last run read, in order, with each one's
compile options and device; the next run of that name reads them on a thread of its own from its
start (while the main thread imports, reads its views and traces), and each program's first call
takes its executable from there. An executable is only ever the cache entry's own, deserialized
with the options and device its call passes (anything else is read as before), so the numbers are
the same to the bit.
"""
from __future__ import annotations

import contextlib
import inspect
import json
import threading
from pathlib import Path

MANIFEST_KEYS = 512
"""Most keys kept per name."""
_SIGNATURE = ("cache_key", "compile_options", "backend", "executable_devices")
"""The parameters of JAX's cache read that :meth:`_Reader.get` stands in for."""


def _folder() -> Path | None:
    """Where the lists are kept: ``read_ahead`` in JAX's persistent cache folder; None when it is off."""
    import jax

    root = jax.config.jax_compilation_cache_dir
    return Path(root) / "read_ahead" if root else None


def _is_row(row) -> bool:
    """Whether ``row`` reads as a listed program: [key, options in hex, [[platform, device id], ...]]."""
    return (isinstance(row, list) and len(row) == 3 and isinstance(row[0], str) and isinstance(row[1], str)
            and isinstance(row[2], list) and bool(row[2])
            and all(isinstance(d, list) and len(d) == 2 and isinstance(d[0], str) and isinstance(d[1], int)
                    for d in row[2]))


def _device_ids(devices) -> list[list]:
    return [[d.platform, int(d.id)] for d in devices]


class _Reader:
    """The keys of one name: read ahead on a thread, handed to the first call that asks for one."""

    def __init__(self, path: Path, original, backend, xla_client):
        self.path, self.original, self.backend, self.xla_client = path, original, backend, xla_client
        self.asked: dict[str, tuple[bytes, list]] = {}  # this run's keys: (options, devices)
        self.ready: dict[str, tuple] = {}  # key -> (executable, compile time, options, devices)
        self.loading: dict[str, threading.Event] = {}
        self.lock = threading.Lock()
        self.queue = [row for row in self._listed() if row[2][0][0] == backend.platform]
        self.stop, self.served = False, 0
        self.thread = threading.Thread(target=self._run, name="ipm-read-ahead", daemon=True)
        if self.queue:
            self.thread.start()

    def _listed(self) -> list:
        """The last run's rows (key, options in hex, [[platform, device id], ...]); a file that does
        not read as such is no list."""
        try:
            rows = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return []
        return [tuple(r) for r in rows] if isinstance(rows, list) and all(map(_is_row, rows)) else []

    def _run(self) -> None:
        """Read the listed keys in turn (no import and no set-up on this thread: a module imported
        on two threads at once can be seen half made)."""
        by_id = {int(d.id): d for d in self.backend.devices()}
        while not self.stop:
            with self.lock:
                if not self.queue:
                    return
                key, options_hex, devices = self.queue.pop(0)
                if key in self.asked or key in self.ready:
                    continue
                done = self.loading[key] = threading.Event()
            try:
                serialized = bytes.fromhex(options_hex)
                options = self.xla_client.CompileOptions.ParseFromString(serialized)
                listed = self.xla_client.DeviceList(tuple(by_id[i] for _, i in devices))
                executable, seconds = self.original(key, options, self.backend, listed)
                if executable is not None:
                    with self.lock:
                        self.ready[key] = (executable, seconds, serialized, devices)
            except Exception:  # noqa: BLE001 - a key that does not read back is read by its call
                pass
            finally:
                with self.lock:
                    self.loading.pop(key, None)
                done.set()

    def get(self, key, options, backend, devices):
        """``jax._src.compilation_cache.get_executable_and_time``, from what was read ahead where
        the call's options and devices are those it was read with."""
        try:
            got = self._take(key, options, devices)
        except Exception:  # noqa: BLE001 - whatever this JAX makes of the bookkeeping, the call reads its own
            got = None
        return got if got is not None else self.original(key, options, backend, devices)

    def _take(self, key, options, devices) -> tuple | None:
        """The executable and compile time read ahead for this call, or None; ``key`` listed as asked."""
        ids, wanted = _device_ids(devices), options.SerializeAsString()
        with self.lock:
            self.asked.setdefault(key, (wanted, ids))
            waiting = self.loading.get(key)
        if waiting is not None:
            waiting.wait()
        with self.lock:
            got = self.ready.pop(key, None)
        if got is None or got[2] != wanted or got[3] != ids:
            return None
        self.served += 1
        return got[0], got[1]

    def close(self) -> None:
        """Stop reading ahead and keep this run's keys, in the order they were asked, for the next run."""
        with self.lock:
            self.stop, self.queue = True, []
        if self.thread.is_alive():
            self.thread.join()
        self.ready.clear()
        if not self.asked:
            return
        from ipm.io.atomic import atomic_path

        rows = [[key, options.hex(), ids] for key, (options, ids) in list(self.asked.items())[:MANIFEST_KEYS]]
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(self.path) as tmp:
                tmp.write_text(json.dumps(rows))
        except OSError:  # a read-only cache folder: nothing is kept
            pass


_ACTIVE: list = []


@contextlib.contextmanager
def read_ahead(name: str):
    """Within the block, the programs the last run of ``name`` read from JAX's persistent cache
    are read ahead on a thread, and this run's are listed for the next (see the module); the block
    gets the reader (``served``: programs it handed over). Nothing (None) where the cache is off,
    inside another such block, or for a process given one thread (``ipm.runtime.thread_count``:
    the reading thread would be a second core busy)."""
    from ipm.runtime import thread_count

    folder = _folder()
    if folder is None or _ACTIVE or thread_count() < 2:
        yield None
        return
    from jax._src import compilation_cache, xla_bridge
    from jax._src.lib import xla_client

    original = compilation_cache.get_executable_and_time
    if list(inspect.signature(original).parameters) != list(_SIGNATURE):  # another JAX: read as it reads
        yield None
        return
    backend = xla_bridge.get_backend()  # the backend and the cache made here, so the thread sets up nothing
    compilation_cache._get_cache(backend)
    reader = _Reader(folder / f"{name}.json", original, backend, xla_client)
    compilation_cache.get_executable_and_time = reader.get
    _ACTIVE.append(reader)
    try:
        yield reader
    finally:
        _ACTIVE.pop()
        compilation_cache.get_executable_and_time = original
        reader.close()
