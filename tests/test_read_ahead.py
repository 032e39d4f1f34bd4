"""Programs read ahead from JAX's persistent cache: the same executables, so the same numbers."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

RUN = """
import json, sys
import numpy as np
from ipm.runtime import configure_threads
configure_threads(int(sys.argv[2]))
import jax, jax.numpy as jnp
from ipm.read_ahead import read_ahead

x = np.linspace(-1, 1, 48 * 48, dtype=np.float32).reshape(48, 48)
with read_ahead("test") as reader:
    if reader is not None and reader.thread.ident is not None and sys.argv[1] == "wait":
        reader.thread.join()  # everything read ahead before the first call
    out = [np.asarray(jax.jit(lambda a, k=k: jnp.tanh(a * k) @ a.T + k)(x)) for k in range(1, 5)]
print(json.dumps({"served": None if reader is None else reader.served, "out": [o.tobytes().hex() for o in out]}))
"""


def _run(cache, mode: str, threads: int = 2) -> dict:
    env = {**os.environ, "IPM_JAX_CACHE": str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    for name in ("JAX_COMPILATION_CACHE_DIR", "JAX_COMPILATION_CACHE_MAX_SIZE"):
        env.pop(name, None)
    done = subprocess.run([sys.executable, "-c", RUN, mode, str(threads)], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.slow
def test_programs_read_ahead_are_the_cache_s_own_and_give_the_same_numbers(tmp_path):
    """A run lists the programs it read; the next run of the name is handed them from the reading
    thread, with the same results to the bit as without the cache; a listed program whose options
    differ from its call's is read by the call itself; an unreadable list is no list; a run given one
    thread reads nothing ahead (its one core busy)."""
    cache = tmp_path / "jax"
    first = _run(cache, "wait")
    assert first["served"] == 0
    listed = cache / "read_ahead" / "test.json"
    rows = json.loads(listed.read_text())
    assert len(rows) == 4
    second = _run(cache, "wait")
    assert second["served"] == 4 and second["out"] == first["out"]
    assert _run(cache, "wait", threads=1) == {"served": None, "out": first["out"]}
    assert _run("off", "wait") == {"served": None, "out": first["out"]}
    from jax._src.lib import xla_client

    other = xla_client.CompileOptions()
    other.num_replicas = 2  # options no call of this run passes
    rows[0][1] = other.SerializeAsString().hex()
    listed.write_text(json.dumps(rows))
    third = _run(cache, "wait")
    assert third["served"] == 3 and third["out"] == first["out"]
    for broken in ("[[1, 2", "[[1, 2]]", '[["k", "00", [["cpu"]]]]'):
        listed.write_text(broken)
        assert _run(cache, "go") == {"served": 0, "out": first["out"]}
