"""Procedural generators, registered by name (``GENERATORS["dishes"]`` is a class)."""
from ipm.registry import Registry

GENERATORS: Registry = Registry("generator")

from ipm.generators import buildings, dishes, trees  # noqa: E402,F401  (fills the registry)


def get_generator(name: str):
    """An instance of the generator registered as ``name`` (``UserError`` if unknown)."""
    return GENERATORS[name]()
