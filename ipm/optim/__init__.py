"""Search algorithms over generator parameters (ask/tell or pure update functions)."""
from ipm.optim import ga  # noqa: F401  (fills the registry)
from ipm.optim.registry import ALGORITHMS
