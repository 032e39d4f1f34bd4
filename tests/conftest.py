"""Shared fixtures: thread limits before JAX loads, Mitsuba variants actually installed, tiny cases."""
from __future__ import annotations

import os
import tempfile

# JAX's persistent compilation cache in a fresh folder for this run, shared by the test workers and
# the processes the tests start (the CLI, the smoke DAG's jobs): a program compiled once is read
# back everywhere else, as in the workflow, and nothing from an earlier run is used. The
# controller made it and removes it at the end (pytest_unconfigure); workers inherit it.
if "IPM_JAX_CACHE" not in os.environ:
    os.environ["IPM_JAX_CACHE"] = tempfile.mkdtemp(prefix="ipm-test-jax-")
    _OWN_CACHE = os.environ["IPM_JAX_CACHE"]
else:
    _OWN_CACHE = None

from ipm.runtime import configure_threads  # noqa: E402

THREADS = max(1, min(2, len(os.sched_getaffinity(0)) // int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))))
"""Threads of a test process: 2, or its share of the CPUs where test workers run side by side."""

_AS_THE_PACKAGE = "IPM_TEST_AS_THE_PACKAGE"
"""Set to 1 in the processes :func:`as_the_package` starts, whose XLA flags the package chose."""

TEST_COMPILE = "--xla_backend_optimization_level=0"
"""XLA's CPU programs built without LLVM's optimization passes, for the tests only: most tests compile
more than they run, and those passes are most of a compile (docs/decisions.md, 'Compile flag')."""

# before anything imports jax; XLA's older CPU code generator for fusions (ipm.runtime.QUICK_COMPILE)
# and TEST_COMPILE here and, through XLA_FLAGS, in every process the tests start; the package uses the
# first for its diff fits, where compiling is much of a fit too. The tests check behaviour and
# tolerances, which neither flag moves.
if os.environ.get(_AS_THE_PACKAGE) != "1":
    if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{TEST_COMPILE} {os.environ.get('XLA_FLAGS', '')}".strip()
    configure_threads(THREADS, quick_compile=True)

import numpy as np  # noqa: E402
import pytest  # noqa: E402


def _variants():
    from ipm.runtime import _point_drjit_at_llvm19

    _point_drjit_at_llvm19()
    import drjit as dr
    import mitsuba as mi

    found = []
    if "llvm_ad_rgb" in mi.variants() and dr.has_backend(dr.JitBackend.LLVM):
        found.append("llvm_ad_rgb")
    if "cuda_ad_rgb" in mi.variants() and dr.has_backend(dr.JitBackend.CUDA):
        found.append("cuda_ad_rgb")
    return found


@pytest.fixture(scope="session", params=_variants() or [pytest.param(None, marks=pytest.mark.skip("no AD variant"))])
def variant(request):
    """Each differentiable Mitsuba variant available here (LLVM always in CI, CUDA where present)."""
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(request.param)
    dr.set_thread_count(THREADS)
    yield request.param
    dr.flush_malloc_cache()


@pytest.fixture(scope="session")
def mitsuba_cpu():
    """Mitsuba on the LLVM backend (for tests that need rendering, not a variant sweep)."""
    from ipm.runtime import set_mitsuba_variant

    return set_mitsuba_variant("cpu", THREADS)


_SLOW_S = 60.0
_session: dict = {}


def _mappings() -> int:
    """This process's memory mappings (Linux; 0 elsewhere)."""
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_code(request):
    """After each test module, drop Dr.Jit's compiled kernels and JAX's compiled programs: each
    holds memory mappings of its own, and the whole suite in one process reached the kernel's
    limit (``vm.max_map_count``, 65,530): the next compile failed and the process hung (the
    failure signal handler that pycolmap installs deadlocked in the unwinder)."""
    yield
    import gc
    import sys

    held = _mappings()
    if "drjit" in sys.modules:
        sys.modules["drjit"].flush_kernel_cache()
    if "jax" in sys.modules:
        sys.modules["jax"].clear_caches()
    gc.collect()
    if held > _session.get("peak", (0,))[0]:
        _session["peak"] = (held, _mappings(), request.node.name)


def slow_except(values, *fast):
    """``values`` for ``pytest.mark.parametrize``, each marked ``slow`` unless its first element is
    in ``fast``: the fast tier (``-m "not slow"``) keeps those, the full suite runs every one."""
    out = []
    for v in values:
        args = v if isinstance(v, tuple) else (v,)
        out.append(v if args[0] in fast else pytest.param(*args, marks=pytest.mark.slow))
    return out


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def tiny_case(tmp_path_factory, mitsuba_cpu):
    """cup_1 rendered at 64 px with 2 views (input + one more)."""
    return synthesized(tmp_path_factory, "cup_1", n_views=2, res=64, spp=4)


def part_volumes(mesh) -> np.ndarray:
    """Signed volume of each part of a closed trimesh mesh (faces joined through shared edges, as
    ``mesh.split`` parts them), summed per part in one pass: a tree's thousands of leaves made
    ``split`` and a volume per part most of a generator test's time."""
    import trimesh

    part = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    tri = np.asarray(mesh.vertices, float)[mesh.faces]
    return np.bincount(part, np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0)


def package_env() -> dict:
    """This process's environment for a process whose XLA flags the package chooses (no
    ``XLA_FLAGS``, and this module leaves them alone there)."""
    return {**{k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}, _AS_THE_PACKAGE: "1"}


def as_the_package(target: str, *args, quick_compile: bool = False, **kwargs):
    """``target`` ("module:function") called with ``args`` and ``kwargs`` in a fresh process whose
    programs XLA compiles with the package's flags, not :data:`TEST_COMPILE` (``quick_compile`` as
    for the diff fits, else as for the trainings), and what it returns, pickled back: for a check
    that needs the package's rounding, or programs that run far longer than they compile (a
    training's unoptimized steps ran a fifth longer, 76 s against 63 s for the occupancy network's)."""
    import pickle
    import subprocess
    import sys
    from pathlib import Path

    code = ("import importlib, pickle, sys; from ipm.runtime import configure_threads; "
            "t, a, k, n, q = pickle.loads(open(sys.argv[1], 'rb').read()); configure_threads(n, quick_compile=q); "
            "m, f = t.split(':'); r = getattr(importlib.import_module(m), f)(*a, **k); "
            "open(sys.argv[2], 'wb').write(pickle.dumps(r))")
    env = package_env()
    with tempfile.TemporaryDirectory() as tmp:
        call, result = Path(tmp) / "call.pkl", Path(tmp) / "result.pkl"
        call.write_bytes(pickle.dumps((target, args, kwargs, THREADS, quick_compile)))
        res = subprocess.run([sys.executable, "-c", code, str(call), str(result)], cwd=Path(__file__).parents[1],
                             env=env, capture_output=True, text=True, timeout=1200)
        assert res.returncode == 0, res.stderr[-3000:]
        return pickle.loads(result.read_bytes())


def synthesized(tmp_path_factory, case: str, n_views: int, res: int, spp: int):
    """The folder of ``case`` rendered by ``ipm synth`` in a fresh temporary directory."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("synth") / case
    synthesize(case, out, n_views=n_views, res=res, spp=spp, progress=False)
    return out


def pytest_configure(config):
    import time

    _session.update(config=config, start=time.monotonic())


def pytest_unconfigure(config):
    if _OWN_CACHE is not None:
        import shutil

        shutil.rmtree(_OWN_CACHE, ignore_errors=True)


MAX_WORKERS = 4
"""``-n auto`` (pyproject's addopts) starts one worker per CPU up to this many: each worker holds
JAX, Mitsuba and open3d (a few GiB), and few modules are long enough to keep more of them busy."""


def pytest_xdist_auto_num_workers(config):
    return max(1, min(len(os.sched_getaffinity(0)), MAX_WORKERS))


FIRST_MODULES = ("test_workflow.py", "test_slurm.py")
"""Run first, in this order: the smoke run of the whole DAG takes minutes, longer than any other
module; the SLURM cluster's DAG mostly waits on its scheduler, and beside the smoke run (whose
Snakemake has two cores to fill) that wait costs no core, where at the end it left one idle."""


def pytest_collection_modifyitems(config, items):
    """:data:`FIRST_MODULES` first, then the other modules with slow tests, then the rest (each
    module goes to one worker whole, ``--dist loadfile``): the long ones start while the short
    ones fill the other workers, instead of ending the run alone."""
    has_slow = {item.path for item in items if item.get_closest_marker("slow")}
    first = {name: i for i, name in enumerate(FIRST_MODULES)}
    items.sort(key=lambda item: (first.get(item.path.name, len(first)), item.path not in has_slow))


def pytest_runtest_logreport(report):
    """Name each test phase over a minute as it ends, with the time since the session began: a CI
    log cut off by its time limit still says where the time went."""
    tr = _session["config"].pluginmanager.get_plugin("terminalreporter") if _session else None
    if report.duration >= _SLOW_S and tr is not None:
        import time

        tr.write_line(f"[slow] {report.nodeid} ({report.when}) {report.duration:.0f} s, "
                      f"{time.monotonic() - _session['start']:.0f} s into the session")


def pytest_terminal_summary(terminalreporter):
    """The most memory mappings the process held at the end of a test module, against the limit."""
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            limit = f.read().strip()
    except OSError:
        return
    held, left, module = _session.get("peak", (0, 0, "none"))
    terminalreporter.write_line(f"memory mappings: at most {held} at a module's end ({module}; {left} after "
                                f"releasing compiled code; vm.max_map_count {limit})")
