"""Moves of the differentiable search: what a generator (or an unknown camera) adds to the generic loop.

A move has a name, the phase it runs in, its settings (a small frozen dataclass beside it), whether
it applies to a problem, its cost in evaluations (the progress bar adds them up) and a call that
takes a candidate and a :class:`~ipm.search.trial.Trial`. Phases, in the loop's order:

- ``memetic``: extra runs of the memetic stage, each holding some genes (:meth:`Move.holds`);
- ``finalist``: each finalist of the memetic stage, at its width, move by move (a move may return
  several candidates, twins of one lineage, each refined through the first stage);
- ``stage``: before every refinement stage, all candidates;
- ``last``: before the last refinement stage, all candidates, move by move;
- ``refine``: each candidate just before its Adam run of a stage;
- ``end``: the one result, after the last stage.

A generator lists the moves it wants by name (``Generator.moves``); a camera of unknown lens adds
:data:`UNKNOWN_CAMERA_MOVES`. Adding a move: a module here that registers it (every module of this
package is imported with it), and its name in the generators' lists.
"""
import importlib
import pkgutil

from ipm.search.moves.base import MOVES, PHASES, UNKNOWN_CAMERA_MOVES, Move, moves_for, register, settings_classes

for _module in pkgutil.iter_modules(__path__):
    if _module.name != "base":
        importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["MOVES", "PHASES", "UNKNOWN_CAMERA_MOVES", "Move", "moves_for", "register", "settings_classes"]
