"""Named settings of the differentiable path: each group with its owner, overridden by name.

A profile holds one settings dataclass per owner: the loop (``ipm.search.loop.LoopSettings``), the
memetic stage and every Adam run (``ipm.optim.memetic.MemeticSettings``), the loss
(``ipm.search.objective.ObjectiveSettings``) and each move (``ipm.search.moves``). Setting names are
unique across owners, so the command line and a config's ``settings:`` name them flatly.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

from ipm.errors import UserError
from ipm.optim.memetic import MemeticSettings
from ipm.search.loop import LoopSettings
from ipm.search.moves import settings_classes
from ipm.search.objective import ObjectiveSettings



def owners() -> tuple[type, ...]:
    """The settings classes a profile holds one of each: the loop's, the memetic stage's, the loss's
    and those of the moves registered now."""
    return (LoopSettings, MemeticSettings, ObjectiveSettings, *settings_classes())


def owner_of() -> dict[str, type]:
    """Each setting's name -> the class that owns it; two owners of one name are an error."""
    found: dict[str, type] = {}
    for cls in owners():
        for name in cls.names():
            if name in found:
                raise RuntimeError(f"setting {name!r} belongs to both {found[name].__name__} and {cls.__name__}")
            found[name] = cls
    return found


@dataclass(frozen=True)
class DiffProfile:
    """One instance of each settings class of :func:`owners`."""

    parts: tuple

    def of(self, cls):
        """The settings of owner ``cls``."""
        for part in self.parts:
            if type(part) is cls:
                return part
        raise KeyError(cls.__name__)

    @property
    def loop(self) -> LoopSettings:
        return self.of(LoopSettings)

    @property
    def memetic(self) -> MemeticSettings:
        return self.of(MemeticSettings)

    @property
    def objective(self) -> ObjectiveSettings:
        return self.of(ObjectiveSettings)

    def as_dict(self) -> dict:
        """Every setting by name (params.json's ``settings``)."""
        return {k: v for part in self.parts for k, v in asdict(part).items()}

    def updated(self, **overrides) -> DiffProfile:
        """A copy with ``overrides`` (flat names); ``UserError`` for unknown names or bad values."""
        owner = owner_of()
        unknown = sorted(set(overrides) - set(owner))
        if unknown:
            raise UserError(f"unknown diff setting(s) {', '.join(unknown)} (known: {', '.join(sorted(owner))})")
        return DiffProfile(tuple(part.updated(**{k: v for k, v in overrides.items() if owner[k] is type(part)})
                                 for part in self.parts))


PROFILES = {
    "paper": {},
    # default: sizes and stages chosen on dev (docs/decisions.md, 'Memetic stage size', 'Last stage length' and
    # the sections named in each setting's docstring)
    "default": dict(population=16, ga_iterations=12, adam_per_iteration=64, memetic_res=96,
                    refine_res=(128, 256), refine_iterations=(100, 300), refine_candidates=3, plan_check=0.96,
                    decide_steps=30, decide_rounds=3, decide_shares=(0.3, 0.6), decide_kinds=3, sight_steps=90,
                    place_steps=40, focal_sweep=3, pitch_sweep=2,
                    pitch_starts=(7.5, 22.5, 37.5, 52.5)),
    "smoke": dict(population=4, ga_iterations=2, adam_per_iteration=6, memetic_res=32,
                  refine_res=(48,), refine_iterations=(4,), output_lod=0, refine_lod=0, spp=2,
                  polish_sweeps=1, polish_steps=1, focal_sweep=1, focal_steps=1),
}
"""Profiles by name, as the settings they change from the field defaults (``paper``: the authors'
memetic settings with refinement at 256 and 512 px)."""


def get_profile(name: str, **overrides) -> DiffProfile:
    """The named profile with ``overrides`` applied; ``UserError`` for unknown names or bad values."""
    if name not in PROFILES:
        raise UserError(f"unknown profile {name!r} (known: {', '.join(PROFILES)})")
    return DiffProfile(tuple(cls() for cls in owners())).updated(**{**PROFILES[name], **overrides})
