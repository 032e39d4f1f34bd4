"""Shared fixtures: thread limits before JAX loads, Mitsuba variants actually installed, tiny cases."""
from __future__ import annotations

import os

# no persistent compilation cache in the tests (cold, as on a fresh machine): twice a full run hung
# for good in JAX deserialising a cached program at the same test, which passes alone
os.environ.setdefault("IPM_JAX_CACHE", "off")

from ipm.runtime import configure_threads  # noqa: E402

configure_threads(2)  # before anything imports jax

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
    dr.set_thread_count(2)
    yield request.param
    dr.flush_malloc_cache()


@pytest.fixture(scope="session")
def mitsuba_cpu():
    """Mitsuba on the LLVM backend (for tests that need rendering, not a variant sweep)."""
    from ipm.runtime import set_mitsuba_variant

    return set_mitsuba_variant("cpu", 2)


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def tiny_case(tmp_path_factory, mitsuba_cpu):
    """cup_1 rendered at 64 px with 2 views (input + one more)."""
    return synthesized(tmp_path_factory, "cup_1", n_views=2, res=64, spp=4)


def synthesized(tmp_path_factory, case: str, n_views: int, res: int, spp: int):
    """The folder of ``case`` rendered by ``ipm synth`` in a fresh temporary directory."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("synth") / case
    synthesize(case, out, n_views=n_views, res=res, spp=spp, progress=False)
    return out
