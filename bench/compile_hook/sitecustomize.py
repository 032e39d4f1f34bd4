"""Loaded by every Python process that ``bench/compile_profile.py`` starts (its folder leads
``PYTHONPATH``): where ``IPM_COMPILE_PROFILE`` names a folder, records this process's JAX compiles
(XLA's backend compile, tracing and lowering; persistent-cache hits and misses, by program name;
each compile with its programs' argument shapes and its cache key) with the pytest test running at the time
(``PYTEST_CURRENT_TEST``, inherited by the processes a test starts), and writes them there as
``<pid>.json`` when the process ends. Elsewhere it does nothing."""
from __future__ import annotations

import atexit
import json
import logging
import os
import sys

_FOLDER = os.environ.get("IPM_COMPILE_PROFILE")
_EVENTS = {"/jax/core/compile/backend_compile_duration": "compile",
           "/jax/core/compile/jaxpr_trace_duration": "trace",
           "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
           "/jax/compilation_cache/cache_retrieval_time_sec": "read"}


def _test() -> str:
    return os.environ.get("PYTEST_CURRENT_TEST", "").split(" ")[0] or "-"


if _FOLDER:
    _records: list = []
    _state = {"listening": False, "program": None, "shapes": None, "key": None}

    def _on_duration(event: str, seconds: float, **_):
        kind = _EVENTS.get(event)
        if kind == "compile":  # the program its cache miss named; "?" where none was logged
            _records.append((kind, _test(), _state["program"], seconds, _state["shapes"], _state["key"]))
            # a compile whose lowering or lookup logged none gets none
            _state["program"] = _state["shapes"] = _state["key"] = None
        elif kind is not None:
            _records.append((kind, _test(), None, seconds))

    class _CacheLog(logging.Handler):
        """JAX's compiler log names each program as it looks it up in the persistent cache (before
        the compile whose duration follows); the first record also subscribes to the durations,
        JAX being imported by then."""

        def emit(self, record):
            if not self._listening():
                return
            message = record.getMessage()
            name = message.split("'")[1] if message.count("'") >= 2 else "?"
            if message.startswith("PERSISTENT COMPILATION CACHE MISS"):
                _state["program"] = name
                _state["key"] = message.rsplit(" with key ", 1)[-1].strip("'") if " with key " in message else None
                _records.append(("miss", _test(), name, 0.0))
            elif message.startswith("Persistent compilation cache hit"):
                _records.append(("hit", _test(), name, 0.0))

        @staticmethod
        def _listening() -> bool:
            if not _state["listening"] and "jax" in sys.modules:
                try:
                    import jax.monitoring

                    jax.monitoring.register_event_duration_secs_listener(_on_duration)
                    _state["listening"] = True
                except (ImportError, AttributeError):
                    pass
            return _state["listening"]

    class _ShapesLog(logging.Handler):
        """JAX names each program's argument shapes as it lowers it (before the cache lookup)."""

        def emit(self, record):
            message = record.getMessage()
            if message.startswith("Compiling ") and " with global shapes and types " in message:
                _state["shapes"] = message.split(" with global shapes and types ", 1)[1].split(". Argument", 1)[0]

    for _name, _handler in (("jax._src.compiler", _CacheLog()), ("jax._src.interpreters.pxla", _ShapesLog())):
        _log = logging.getLogger(_name)
        _log.setLevel(logging.DEBUG)
        _log.addHandler(_handler)
        _log.propagate = False  # its debug lines would reach stderr (the CLI's one-line errors)

    @atexit.register
    def _write():
        times = os.times()
        path = os.path.join(_FOLDER, f"{os.getpid()}.json")
        with open(path + ".part", "w") as f:
            json.dump({"argv": [os.path.basename(a) for a in sys.argv[:3]], "cpu_s": times.user + times.system,
                       "records": _records}, f)
        os.replace(path + ".part", path)
