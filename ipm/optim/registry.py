"""The registry of ask/tell search algorithms (filled by ``ipm.optim``)."""
from ipm.registry import Registry

ALGORITHMS: Registry = Registry("algorithm")
"""Ask/tell search algorithms by name (``ALGORITHMS["ga"]`` is :class:`ipm.optim.ga.TreeGA`)."""
