"""Procedural generators, registered by name (``GENERATORS["dishes"]`` is a class)."""
from ipm.generators import buildings, dishes, trees  # noqa: F401  (fills the registry)
from ipm.generators.base import GENERATORS


def get_generator(name: str):
    """An instance of the generator registered as ``name`` (``UserError`` if unknown)."""
    return GENERATORS[name]()
