"""The registry of losses for the genetic search (filled by ``ipm.losses``)."""
from ipm.registry import Registry

LOSSES: Registry = Registry("loss")
