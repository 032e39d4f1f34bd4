"""The move base class, the registry of moves and the phases they run in (``ipm.search.moves``)."""
from __future__ import annotations

from ipm.registry import Registry

PHASES = ("memetic", "finalist", "stage", "last", "refine", "end")

UNKNOWN_CAMERA_MOVES = ("pitch starts", "focal")
"""Moves a camera of unknown pitch and lens adds to the generator's (``ipm.search.moves.camera``)."""


class Move:
    """Base of the moves: subclasses set ``name``, ``phase``, ``settings`` and implement ``__call__``."""

    name: str = ""
    phase: str = "last"
    settings: type | None = None
    """The move's settings class (``ipm.settings.Settings``), found in a profile by that class."""
    label: str = ""
    """The trace's stage name for the move's rows (default: its name)."""
    steps_before: bool = False
    """True where the move's Adam steps run at the previous stage's width (its scores at this one's)."""

    def applies(self, problem, profile) -> bool:
        """Whether the move runs for ``problem`` under ``profile`` (default: always)."""
        return True

    def cost(self, problem, profile) -> int:
        """Evaluations one candidate costs (the progress bar's share); 0 where unknown."""
        return 0

    def holds(self, problem, profile) -> list[dict[int, float]]:
        """(phase ``memetic``) The genes each extra memetic run holds, as {gene index: value}."""
        return []

    def __call__(self, cand, trial, settings):
        raise NotImplementedError


MOVES: Registry[Move] = Registry("move")


def register(cls: type[Move]) -> type[Move]:
    """Class decorator: register an instance of the move ``cls`` under its name."""
    if cls.phase not in PHASES:
        raise ValueError(f"move {cls.name!r}: unknown phase {cls.phase!r} (known: {', '.join(PHASES)})")
    MOVES.register(cls.name)(cls())
    return cls


def moves_for(problem) -> list[Move]:
    """The moves of ``problem``: its generator's, then an unknown camera's, in that order."""
    names = tuple(problem.generator.moves) + (UNKNOWN_CAMERA_MOVES if problem.camera is not None else ())
    return [MOVES[name] for name in names]


def settings_classes() -> list[type]:
    """The settings class of every registered move that has one."""
    found = [MOVES[name].settings for name in MOVES.names() if MOVES[name].settings is not None]
    return list(dict.fromkeys(found))

