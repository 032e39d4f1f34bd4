"""Procedural generators, registered by name (``GENERATORS["dishes"]`` is a class)."""
from functools import lru_cache

from ipm.generators import buildings, dishes, trees  # noqa: F401  (fills the registry)
from ipm.generators.base import GENERATORS


def get_generator(name: str):
    """The instance of the generator registered as ``name`` (``UserError`` if unknown), one per
    process: a generator holds no state but its traced programs and topologies (cached per
    instance), which every caller then shares instead of tracing them again."""
    return _instance(GENERATORS[name])


@lru_cache(maxsize=None)
def _instance(cls):
    return cls()
