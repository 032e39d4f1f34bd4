"""Process-wide settings that must happen in entry points: threads, Dr.Jit LLVM path, Mitsuba variant.

``mi.set_variant`` and XLA's thread flags are process-global, so they are set here, once,
from the CLI or a test fixture, and never at import time of a library module.
"""
from __future__ import annotations

import contextlib
import ctypes
import importlib.abc
import importlib.util
import os
import sys
from pathlib import Path

from ipm.errors import UserError

_LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM-19.so",
)


QUICK_COMPILE = "--xla_cpu_use_fusion_emitters=false --xla_cpu_experimental_ynn_fusion_type="
"""XLA's older CPU code generator for fusions (a building's generator pullback compiles in half the
time) and no YNNPACK library fusions (the renderer's small dots and reductions over every fragment
cost more in YNNPACK's calls than inline; a fit no longer depends on its thread count); the
networks' programs (diffSDF-style's, the occupancy network's) run up to a third longer; float
results differ from the default's in the last bits (docs/decisions.md, 'Compile flag')."""


def configure_threads(threads: int, device: str = "cpu", quick_compile: bool = False) -> None:
    """Limit XLA (must run before ``import jax``) and BLAS to ``threads`` host threads; with
    ``quick_compile`` (a fit that compiles its programs per case: ``Method.compiles``), compile with
    :data:`QUICK_COMPILE`, unless ``XLA_FLAGS`` already chooses.

    On ``device="cpu"`` JAX is kept on the host so it never probes for accelerators.
    """
    threads = max(1, int(threads))
    flags = os.environ.get("XLA_FLAGS", "")
    if quick_compile and "xla_cpu_use_fusion_emitters" not in flags:
        flags = f"{QUICK_COMPILE} {flags}".strip()  # first: XLA reads flags up to the first word without "--"
    if "intra_op_parallelism_threads" not in flags:  # a word without "--": last
        flags = (f"{flags} --xla_cpu_multi_thread_eigen={'true' if threads > 1 else 'false'} "
                 f"intra_op_parallelism_threads={threads}")
    if not xla_started():
        os.environ["XLA_FLAGS"] = flags.strip()
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(threads))
    if device == "cpu":
        os.environ.setdefault("JAX_PLATFORMS", "cpu")
    cache = compile_cache_dir()
    if cache and "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        os.environ["JAX_COMPILATION_CACHE_DIR"] = cache
        # Small programs are kept too: a fit compiles about a hundred (the generator's vertices, the
        # regressor, the renderer's) at 0.02-0.4 s each, 4-5 s of a cup's fit if each process
        # compiled them again; not the quickest (eager array operations), whose writes kept a second
        # core of a one-thread job busy (docs/decisions.md, 'Small programs kept').
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.02")
        # Jobs running side by side share the folder. JAX writes an entry in place and reads it
        # unlocked unless the cache has a size limit; with one it locks the folder (filelock)
        # around every read and write, so no process reads a half-written program.
        os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(CACHE_MAX_BYTES))
        repair_compile_cache(cache)
        if "jax" in sys.modules:
            sys.modules["jax"].config.update("jax_compilation_cache_dir", cache)
            sys.modules["jax"].config.update("jax_compilation_cache_max_size",
                                             int(os.environ["JAX_COMPILATION_CACHE_MAX_SIZE"]))
    keep_freed_memory()
    global _THREADS
    _THREADS = threads
    if "jax" in sys.modules:
        _start_xla_cpu(threads)
    elif not _AfterImport.waiting("jax"):
        sys.meta_path.insert(0, _AfterImport("jax", lambda module: _start_xla_cpu(_THREADS)))
    _keep_fault_handlers("pycolmap")
    _defer_plotly_viewer()


def xla_started() -> bool:
    """Whether XLA has read ``XLA_FLAGS`` in this process (a JAX backend is up). Flags changed after
    that do not reach the compiler but still enter the keys of JAX's persistent compilation cache,
    which would then file programs compiled under one set of flags as if under another: a later
    process reading them would compute other numbers than one that compiled them itself."""
    if "jax" not in sys.modules:
        return False
    from jax._src import xla_bridge

    return xla_bridge.backends_are_initialized()


_THREADS: int | None = None
CACHE_MAX_BYTES = 4 << 30
"""Size limit of JAX's persistent compilation cache (least recently used entries go first)."""


KEEP_FREED_BYTES = 1 << 30
"""glibc's mmap and trim thresholds set by :func:`keep_freed_memory`."""


def keep_freed_memory() -> None:
    """Have glibc keep the memory this process frees for its next allocations. XLA's CPU programs
    allocate their buffers afresh at every call; by default glibc maps the large ones from the
    system each time and gives freed heap tops back, so every loss evaluation paid page faults (a
    warm cup's fit: 5.8 s of system time in 12.8 s, 0.9 s with this; docs/decisions.md, 'Freed
    memory kept'). Not where the ``MALLOC_*`` variables choose otherwise, nor off glibc."""
    if not sys.platform.startswith("linux") or any(k.startswith("MALLOC_") for k in os.environ):
        return
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):  # another C library (musl)
        return
    m_trim_threshold, m_mmap_threshold = -1, -3
    mallopt(m_mmap_threshold, KEEP_FREED_BYTES)
    mallopt(m_trim_threshold, KEEP_FREED_BYTES)


def compile_cache_dir() -> str | None:
    """Folder of JAX's persistent compilation cache: ``IPM_JAX_CACHE`` (``off`` for none), else
    ``$XDG_CACHE_HOME/ipm/jax`` (``~/.cache/ipm/jax``). A reconstruction compiles its loss once
    per topology and resolution, seconds each and most of a cup's time with the JAX renderer; the
    cache keeps them for the next process (the workflow's next seed: cup_1 42 s cold, 14 s warm).
    Entries are keyed by the program and JAX's version, so a stale one is never used."""
    value = os.environ.get("IPM_JAX_CACHE", "")
    if value.lower() in ("off", "0", "none"):
        return None
    if value:
        return value
    return str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ipm" / "jax")


def repair_compile_cache(folder: str | Path) -> None:
    """Give every entry of JAX's compilation cache in ``folder`` that lacks one its access-time file
    (the entry's modification time). With a size limit JAX reads every entry's access time before
    it writes a new one, and one missing file (an entry written without the limit, or by a process
    killed between the two writes) makes every later write fail: the cache then never grows and
    each process compiles again (a building's loss: 17 s, 4 s cached)."""
    folder = Path(folder)
    for entry in folder.glob("*-cache") if folder.is_dir() else ():
        atime = entry.with_name(entry.name[: -len("-cache")] + "-atime")
        if not atime.exists():
            try:
                atime.write_bytes(entry.stat().st_mtime_ns.to_bytes(8, "little"))
            except OSError:  # removed by an eviction meanwhile, or a read-only folder
                pass


def thread_count() -> int:
    """CPU threads this process may use: the count given to :func:`configure_threads`, else every
    CPU it may run on. Libraries that take a thread count per call (open3d's ray casting, COLMAP)
    get it from here."""
    if _THREADS:
        return _THREADS
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _start_xla_cpu(threads: int) -> None:
    """Start XLA's CPU client with ``threads`` threads in its pools.

    XLA sizes its CPU pools (``tf_XLAEigen``, the client's) by the CPUs the process may run on
    when the client starts and ignores ``intra_op_parallelism_threads``: with jax 0.10 the
    diffSDF-style baseline kept 1.7 cores busy under ``--threads 1``. So the client is started
    with the calling thread pinned to ``threads`` CPUs (new threads inherit that mask), and then
    every thread of the process gets the whole mask back, so the scheduler can still move the
    job to whichever core is free. Does nothing more when ``threads`` covers every CPU, or where
    the system has no CPU affinity (not Linux). With one thread, JAX's CPU programs run on the
    calling thread (no asynchronous dispatch).
    """
    if threads == 1:
        # one thread computes on the calling thread: JAX's CPU client otherwise runs each program on
        # a thread of its own while Python goes on tracing the next (a warm one-thread smoke fit
        # with this: 4.9 s of CPU in 4.9 s of wall; XLA's compiler still uses two threads at times)
        import jax

        jax.config.update("jax_cpu_enable_async_dispatch", False)
    if not hasattr(os, "sched_setaffinity") or not os.path.isdir("/proc/self/task"):
        return
    full = os.sched_getaffinity(0)
    if threads >= len(full):
        return
    os.sched_setaffinity(0, sorted(full)[:threads])
    try:
        import jax
        import jax.numpy as jnp

        with jax.default_device(jax.devices("cpu")[0]):  # pools made at the first compile and run, too
            jax.jit(lambda x: jnp.sin(x) @ x)(jnp.ones((4, 4))).block_until_ready()
    finally:
        for tid in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(tid), full)
            except OSError:  # the thread ended meanwhile
                pass


class _AfterImport(importlib.abc.MetaPathFinder):
    """Runs ``hook(module)`` once, right after the top-level module ``name`` is first imported
    (and ``before()``, if given, right before)."""

    def __init__(self, name: str, hook, before=None):
        self.name, self.hook, self.before = name, hook, before

    @staticmethod
    def waiting(name: str) -> bool:
        """Whether a hook for ``name`` is installed and its module not yet imported."""
        return any(isinstance(f, _AfterImport) and f.name == name for f in sys.meta_path)

    def find_spec(self, fullname, path=None, target=None):
        if fullname != self.name:
            return None
        sys.meta_path.remove(self)
        if self.before is not None:
            self.before()
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None:
            return spec
        loader, hook = spec.loader, self.hook

        class Loader(importlib.abc.Loader):
            def create_module(self, spec):
                return loader.create_module(spec)

            def exec_module(self, module):
                loader.exec_module(module)
                hook(module)

        spec.loader = Loader()
        return spec


_FATAL_SIGNALS = ("SIGSEGV", "SIGBUS", "SIGILL", "SIGFPE", "SIGABRT", "SIGTERM")


def _signal_actions() -> dict:
    """The C-level actions of the fatal signals (raw ``struct sigaction``s, by signal number).
    Linux only (an empty dict elsewhere)."""
    import ctypes
    import signal

    if not sys.platform.startswith("linux"):
        return {}
    libc, out = ctypes.CDLL(None), {}
    for number in (int(getattr(signal, name)) for name in _FATAL_SIGNALS):
        action = ctypes.create_string_buffer(512)  # glibc's struct sigaction is 152 bytes
        if libc.sigaction(number, None, action) == 0:
            out[number] = action
    return out


def _set_signal_actions(actions: dict) -> None:
    """Install ``actions`` (from :func:`_signal_actions`)."""
    import ctypes

    libc = ctypes.CDLL(None)
    for number, action in actions.items():
        libc.sigaction(number, action, None)


def _keep_fault_handlers(module: str) -> None:
    """Put the fatal signals' handlers back after ``module``'s first import: pycolmap installs
    glog's failure handler, which deadlocked a process that crashed inside the C++ unwinder (it
    unwinds again for its stack trace and waits for the unwinder's lock forever), so a crash
    hung instead of ending. Python's faulthandler, or the default action, stays in charge."""
    if module in sys.modules or _AfterImport.waiting(module):
        return
    saved: dict = {}
    sys.meta_path.insert(0, _AfterImport(module, lambda _: _set_signal_actions(saved),
                                         before=lambda: saved.update(_signal_actions())))


PLOTLY_VIEWER = "open3d.visualization.draw_plotly"
"""The module of open3d's plotly viewer, which open3d imports with itself (dash and plotly)."""


def _defer_plotly_viewer() -> None:
    """Let open3d's import skip its plotly viewer (:data:`PLOTLY_VIEWER`, half of open3d's import:
    0.5 of 1.0 s of CPU on the slower kind), which the package never calls: a stand-in module whose
    functions import the viewer when first called. Every process that casts rays (the metrics,
    the GA, the texture stage) starts that much sooner."""
    if "open3d" in sys.modules or PLOTLY_VIEWER in sys.modules:
        return
    import types

    stand_in = types.ModuleType(PLOTLY_VIEWER)

    def viewer():
        if sys.modules.get(PLOTLY_VIEWER) is stand_in:
            del sys.modules[PLOTLY_VIEWER]
        return importlib.import_module(PLOTLY_VIEWER)

    def deferred(name: str):
        if name.startswith("__"):
            raise AttributeError(name)

        def call(*args, **kwargs):
            return getattr(viewer(), name)(*args, **kwargs)

        call.__name__ = call.__qualname__ = name
        return call

    stand_in.__getattr__ = deferred
    sys.modules[PLOTLY_VIEWER] = stand_in


def _point_drjit_at_llvm19() -> None:
    """Dr.Jit's LLVM backend crashes with LLVM 14/15; use Debian's libLLVM 19 when present."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return
    for cand in _LLVM_CANDIDATES:
        if Path(cand).exists():
            os.environ["DRJIT_LIBLLVM_PATH"] = cand
            return


def set_mitsuba_variant(device: str = "cpu", threads: int | None = None):
    """Select ``llvm_ad_rgb`` (cpu) or ``cuda_ad_rgb`` (cuda) and the Dr.Jit thread count."""
    if device not in ("cpu", "cuda"):
        raise UserError(f"unknown device {device!r} (known: cpu, cuda)")
    _point_drjit_at_llvm19()
    import drjit as dr
    import mitsuba as mi

    variant = "llvm_ad_rgb" if device == "cpu" else "cuda_ad_rgb"
    if variant not in mi.variants():
        raise UserError(f"Mitsuba variant {variant} is not available in this installation")
    try:
        mi.set_variant(variant)
    except Exception as exc:  # Dr.Jit raises plain exceptions when the backend is missing
        raise UserError(f"cannot start Mitsuba variant {variant}: {exc}") from None
    if threads is not None and device == "cpu":
        dr.set_thread_count(max(1, int(threads)))
    return mi


@contextlib.contextmanager
def job_clock():
    """Times the block: the yielded dict gets ``wall_seconds`` and ``cpu_seconds`` (user and system
    time of this process's threads and of the children it waited for) when the block ends, so a
    job's time on one kind of CPU can be compared with another's."""
    import time

    t0, c0 = time.perf_counter(), os.times()
    out: dict = {}
    yield out
    c1 = os.times()
    cpu = sum(getattr(c1, k) - getattr(c0, k) for k in ("user", "system", "children_user", "children_system"))
    out.update(wall_seconds=round(time.perf_counter() - t0, 2), cpu_seconds=round(cpu, 2))


def exit_now(code: int = 0):
    """End a finished process with ``code`` at once, past the interpreter's teardown (JAX's backends
    and Mitsuba's JIT freed piece by piece: 0.3-2 s of CPU a job, docs/results.md, "The test
    suite's time"). For the ends of entry points only: everything a job writes is already written
    and closed; standard output, standard error and logging are flushed here."""
    import logging

    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):  # closed or replaced by something without flush
            pass
    os._exit(int(code or 0))


def _cpuinfo() -> dict:
    """The first processor's fields of /proc/cpuinfo (empty where there is none)."""
    out = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if not line.strip():
                break
            key, _, value = line.partition(":")
            out[key.strip()] = value.strip()
    except OSError:
        pass
    return out


def cpu_kind(flags: str | None = None) -> str:
    """The kind of CPU a time was measured on, as docs/results.md ("Machines") names them: on
    x86-64 "AVX-512" or "no AVX-512" (the two kinds of the project's 2-core machines: XLA's, Dr.Jit's
    and BLAS's kernels differ between them), else the architecture; ``flags``: /proc/cpuinfo's."""
    import platform

    arch = platform.machine()
    if flags is None:
        flags = _cpuinfo().get("flags")
    if arch not in ("x86_64", "AMD64") or flags is None:
        return arch or "unknown"
    return "AVX-512" if "avx512f" in flags.split() else "no AVX-512"


def machine_info(threads: int | None = None, device: str = "cpu") -> dict:
    """Where a job ran, for the report's provenance: host, CPU model, kind (:func:`cpu_kind`) and
    count, OS, the job's threads and device (and the GPU's name when it is cuda)."""
    import platform
    import socket

    fields = _cpuinfo()
    cpu = fields.get("model name") or platform.processor() or platform.machine()
    info = {"host": socket.gethostname(), "cpu": cpu, "kind": cpu_kind(fields.get("flags")), "cpus": os.cpu_count(),
            "os": platform.platform(terse=True), "threads": threads, "device": device}
    if device == "cuda":
        import jax

        info["gpu"] = ", ".join(d.device_kind for d in jax.devices())
    return info


def machine_line(info: dict) -> str:
    """One line of :func:`machine_info` for a table cell."""
    cpu = info.get("cpu", "?") + (f" ({info['kind']})" if info.get("kind") else "")
    parts = [info.get("host", "?"), cpu, f"{info.get('cpus', '?')} CPUs", info.get("os", "?")]
    if info.get("gpu"):
        parts.append(info["gpu"])
    return " · ".join(str(p) for p in parts)
