"""Search algorithms over generator parameters (ask/tell or pure update functions)."""
from ipm.registry import Registry

ALGORITHMS: Registry = Registry("algorithm")
"""Ask/tell search algorithms by name (``ALGORITHMS["ga"]`` is :class:`ipm.optim.ga.TreeGA`)."""

from ipm.optim import ga  # noqa: E402,F401  (fills the registry)
