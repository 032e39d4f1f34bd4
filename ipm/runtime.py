"""Process-wide settings that must happen in entry points: threads, Dr.Jit LLVM path, Mitsuba variant.

``mi.set_variant`` and XLA's thread flags are process-global, so they are set here, once,
from the CLI or a test fixture, and never at import time of a library module.
"""
from __future__ import annotations

import os
from pathlib import Path

from ipm.errors import UserError

_LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM-19.so",
)


def configure_threads(threads: int, device: str = "cpu") -> None:
    """Limit XLA (must run before ``import jax``) and BLAS to ``threads`` host threads.

    On ``device="cpu"`` JAX is kept on the host so it never probes for accelerators.
    """
    threads = max(1, int(threads))
    flags = os.environ.get("XLA_FLAGS", "")
    if "intra_op_parallelism_threads" not in flags:
        os.environ["XLA_FLAGS"] = (
            f"{flags} --xla_cpu_multi_thread_eigen={'true' if threads > 1 else 'false'} "
            f"intra_op_parallelism_threads={threads}"
        ).strip()
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(threads))
    if device == "cpu":
        os.environ.setdefault("JAX_PLATFORMS", "cpu")


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
