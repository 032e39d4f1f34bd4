"""Jobs use the cores they declare: a Snakemake rule with ``threads: 1`` must not keep two cores busy."""
from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import package_env

CPU_OVER_WALL = 1.15
"""Most CPU time per second of wall time of a ``--threads 1`` job (1.7 for diffSDF before its threads were bounded)."""


def _cpu_and_wall(args: list[str], env: dict) -> tuple[float, float]:
    """CPU seconds (user + system, the process and its children) and wall seconds of a command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(args, capture_output=True, text=True, env={**env, "PYTHONUNBUFFERED": "1"})
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert res.returncode == 0, res.stderr[-2000:]
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


@pytest.mark.slow
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs 2 CPUs to see a job take more than one")
@pytest.mark.parametrize("command, package_flags", [
    (["reconstruct", "--generator", "dishes", "--profile", "smoke"], False),  # Mitsuba (Dr.Jit) and a JAX generator
    (["baseline", "diffsdf", "--profile", "default", "--n-input-views", "2"], True),  # JAX (XLA) heavy
], ids=["diff", "diffsdf"])
def test_a_one_thread_job_keeps_one_core_busy(command, package_flags, tiny_case, tmp_path):
    """Measured on the job's second run, its programs read from the compilation cache: XLA's
    compiler pipelines a program's emission and its machine code on two threads whatever the
    job's thread count (8-9 % of a cold smoke fit's wall time had both running), and how much a
    first run compiles depends on which tests filled the shared cache before it. The pools that
    compute (XLA's, Dr.Jit's) are what ``--threads`` bounds, and a run that only computes shows
    them (diffSDF kept 1.7 cores busy before its pools were bounded). diffSDF-style's job runs with
    XLA's flags as a user's would, not the tests' (``XLA_FLAGS`` unset): it mostly computes, and its
    unoptimized programs ran twice as long as the package's (two runs 93 s against 45 s, alone)."""
    ipm = [sys.executable, "-m", "ipm.cli"]
    args = [*ipm, *command, "--views", str(Path(tiny_case) / "transforms.json"), "--threads", "1", "--quiet"]
    env = package_env() if package_flags else dict(os.environ)
    _cpu_and_wall([*args, "--out", str(tmp_path / "first")], env)
    cpu, wall = _cpu_and_wall([*args, "--out", str(tmp_path / "out")], env)
    assert cpu <= CPU_OVER_WALL * wall, f"{cpu:.1f} s CPU in {wall:.1f} s wall"


def test_exit_now_keeps_the_status_and_everything_printed():
    """``exit_now`` skips the interpreter's teardown, not the buffered output: a pipe gets all of
    standard output and standard error, and the parent the status."""
    code = ("import logging, sys; from ipm.runtime import exit_now; logging.basicConfig(stream=sys.stderr); "
            "print('x' * 100000, end=''); logging.getLogger('t').warning('w'); print('e', file=sys.stderr); exit_now(3)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 3 and res.stdout == "x" * 100000 and res.stderr.splitlines() == ["WARNING:t:w", "e"]


def test_thread_count_follows_the_configured_threads(monkeypatch):
    import ipm.runtime as rt

    monkeypatch.setattr(rt, "_THREADS", 1)
    assert rt.thread_count() == 1
    monkeypatch.setattr(rt, "_THREADS", None)
    assert rt.thread_count() == len(os.sched_getaffinity(0))


@pytest.mark.parametrize("quick", [False, True])
def test_fits_that_compile_per_case_take_the_quick_code_generator(quick):
    """``quick_compile`` puts the quick code generator among the flags XLA reads (those before the
    first word without "--"); without it, XLA's default; a choice in the environment stays."""
    code = ("import os; from ipm.runtime import configure_threads; "
            f"configure_threads(1, quick_compile={quick}); print(os.environ['XLA_FLAGS'])")
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    flags = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    words = flags.split()
    read = words[:next((i for i, w in enumerate(words) if not w.startswith("--")), len(words))]  # what XLA reads
    assert ("--xla_cpu_use_fusion_emitters=false" in read) == quick and "intra_op_parallelism_threads=1" in words
    from ipm.runtime import QUICK_COMPILE

    assert all((w in read) == quick for w in QUICK_COMPILE.split())  # every quick flag where XLA reads it
    chosen = {**env, "XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}
    flags = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=chosen, check=True).stdout
    assert "fusion_emitters=false" not in flags
    from ipm.methods import METHODS

    assert METHODS["diff"].compiles and not METHODS["diffsdf"].compiles and not METHODS["occnet"].compiles


def test_flags_stay_once_xla_has_read_them():
    """Once a JAX backend is up, ``configure_threads`` leaves ``XLA_FLAGS`` as XLA read them: a
    change would not reach the compiler, only the persistent cache's keys (programs compiled under
    one set of flags filed under another's)."""
    code = ("import os; from ipm.runtime import configure_threads; configure_threads(1); "
            "import jax.numpy as jnp; float(jnp.ones(2).sum()); before = os.environ['XLA_FLAGS']; "
            "configure_threads(2, quick_compile=True); print(before == os.environ['XLA_FLAGS'], "
            "'fusion_emitters' in before)")
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert out.split() == ["True", "False"], out


def test_open3d_is_imported_without_its_plotly_viewer():
    """After ``configure_threads`` open3d's import leaves dash and plotly out (half its import time);
    its plotly viewer still works when called, importing them then."""
    code = ("import sys; from ipm.runtime import configure_threads; configure_threads(1); import numpy as np; "
            "import open3d; print('dash' in sys.modules or 'plotly' in sys.modules); "
            "cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(np.eye(3))); "
            "fig = open3d.visualization.get_plotly_fig([cloud]); print(type(fig).__name__, len(fig.data))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "Figure", "1"], out


def _job_with_cache(folder, code: str) -> subprocess.CompletedProcess:
    """``python -c code`` with IPM_JAX_CACHE at ``folder``, every program cached however quick to
    compile, and none of JAX's own cache settings from this environment."""
    env = {**os.environ, "IPM_JAX_CACHE": str(folder), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env.pop("JAX_COMPILATION_CACHE_MAX_SIZE", None)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)


@pytest.mark.slow
def test_compilation_cache_is_locked_for_processes_side_by_side(tmp_path):
    """Jobs share JAX's persistent compilation cache: it has a size limit, so JAX locks the folder
    around reads and writes (a job that read a half-written program hung), and a second process
    finds the first one's program there."""
    code = ("from ipm.runtime import configure_threads; configure_threads(1)\n"
            "import jax, jax.numpy as jnp, os\n"
            "assert jax.config.jax_compilation_cache_max_size > 0\n"
            "print(float(jax.jit(lambda x: jnp.cumsum(jnp.sin(x) @ x.T))(jnp.ones((200, 200))).sum()))\n")
    runs = [_job_with_cache(tmp_path, code) for _ in range(2)]
    assert all(r.returncode == 0 for r in runs), runs[-1].stderr[-2000:]
    assert runs[0].stdout == runs[1].stdout
    assert (tmp_path / ".lockfile").exists()
    assert any(p.name.endswith("-cache") for p in tmp_path.iterdir())


def test_the_compilation_cache_grows_past_an_entry_without_its_access_time(tmp_path):
    """An entry whose access-time file is missing (written without a size limit, or by a process
    killed between its two writes) made every later write fail; configure_threads restores the
    file, so a job's program is written beside it."""
    old = tmp_path / "jit_old-0123-cache"
    old.write_bytes(b"not a program")
    code = ("from ipm.runtime import configure_threads; configure_threads(1)\n"
            "import jax, jax.numpy as jnp\n"
            "print(float(jax.jit(lambda x: jnp.cumsum(jnp.cos(x) @ x.T))(jnp.ones((150, 150))).sum()))\n")
    res = _job_with_cache(tmp_path, code)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "Error writing persistent compilation cache entry" not in res.stderr
    assert (tmp_path / "jit_old-0123-atime").exists()
    assert len([p for p in tmp_path.iterdir() if p.name.endswith("-cache")]) > 1


@pytest.mark.parametrize("guarded", [True, False])
def test_a_crash_after_importing_pycolmap_is_reported_by_python(guarded):
    """pycolmap installs glog's failure signal handler on import; it once deadlocked a crashed
    test process for good. After ``configure_threads`` (every entry point calls it) Python's
    faulthandler still reports a crash and the process ends; without it, glog's handler runs."""
    setup = "from ipm.runtime import configure_threads; configure_threads(1); " if guarded else ""
    code = f"import faulthandler; faulthandler.enable(); {setup}import pycolmap, ctypes; ctypes.string_at(0)"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode != 0
    assert ("Fatal Python error: Segmentation fault" in res.stderr) == guarded, res.stderr[-2000:]


_FAULTS = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from ipm.runtime import keep_freed_memory
    keep_freed_memory()
faults = []
for _ in range(2):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(8 << 20)
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    del a
print(*faults)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_freed_memory_is_kept_for_the_next_allocation():
    """After ``keep_freed_memory`` a large buffer freed and allocated again (as XLA's programs do at
    every call) costs no page faults; without it, or where a MALLOC_ variable chooses, it does."""
    def again(mode: str, **env) -> float:
        """The second allocation's page faults as a share of the first's."""
        run = subprocess.run([sys.executable, "-c", _FAULTS, mode], capture_output=True, text=True,
                             env={**{k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}, **env})
        assert run.returncode == 0, run.stderr[-2000:]
        first, second = map(int, run.stdout.split())
        return second / first

    assert again("keep") < 0.1
    assert again("none") > 0.5 and again("keep", MALLOC_ARENA_MAX="2") > 0.5


def test_the_cpu_kind_is_read_from_the_flags():
    """Every recorded time names the kind of CPU it came from (docs/results.md, "Machines")."""
    import platform

    from ipm.runtime import cpu_kind, machine_info, machine_line

    if platform.machine() == "x86_64":
        assert cpu_kind("fpu sse2 avx2 avx512f avx512bw") == "AVX-512"
        assert cpu_kind("fpu sse2 avx2 fma") == "no AVX-512"
    info = machine_info(1)
    assert info["kind"] == cpu_kind() and f"({info['kind']})" in machine_line(info)


def test_the_job_clock_counts_the_cpu_time_of_every_thread():
    """A job's CPU seconds beside its wall seconds: two threads that each burn 0.3 s of their own
    CPU time count 0.6 s (to the clock's tick) however the cores are shared (the GIL is released
    while hashing), a sleep next to nothing."""
    import hashlib
    import threading

    from ipm.runtime import job_clock

    def burn():
        start = time.thread_time()
        while time.thread_time() - start < 0.3:
            hashlib.sha256(b"x" * 100_000).digest()

    with job_clock() as clock:
        time.sleep(0.3)
    assert clock["wall_seconds"] >= 0.3 and clock["cpu_seconds"] < 0.1
    with job_clock() as clock:
        threads = [threading.Thread(target=burn) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    # 0.6 s less the process clock's tick (10 ms) per thread and end: one thread's share would be 0.3 s
    assert 0.55 <= clock["cpu_seconds"] < 1.0, clock
