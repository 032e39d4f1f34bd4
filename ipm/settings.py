"""One mechanism for every group of settings: frozen dataclasses whose field types say what is valid.

A field's annotation is checked when the settings are made (from a profile, the command line or
a config's ``settings:``): ``int`` (not a bool), ``float`` (finite; an int is accepted), ``bool``,
``str``, ``Literal[...]`` (one of the values), ``tuple[T, ...]`` (a list is turned into a tuple),
``T | None``, and ``Annotated[T, Range(lo, hi)]`` for bounds. A bad value or an unknown name is a
``UserError`` of one line naming the setting.
"""
from __future__ import annotations

import math
import types
import typing
from dataclasses import dataclass, fields, replace
from functools import lru_cache

import numpy as np

from ipm.errors import UserError


@dataclass(frozen=True)
class Range:
    """Bounds of a number: ``lo <= v <= hi`` (either may be None), strict where ``open_lo``/``open_hi``."""

    lo: float | None = None
    hi: float | None = None
    open_lo: bool = False
    open_hi: bool = False

    def holds(self, v) -> bool:
        return ((self.lo is None or (v > self.lo if self.open_lo else v >= self.lo))
                and (self.hi is None or (v < self.hi if self.open_hi else v <= self.hi)))

    def __str__(self) -> str:
        lo = "" if self.lo is None else f"{'>' if self.open_lo else '>='} {self.lo:g}"
        hi = "" if self.hi is None else f"{'<' if self.open_hi else '<='} {self.hi:g}"
        return " and ".join(p for p in (lo, hi) if p)


def at_least(lo: float) -> Range:
    return Range(lo)


UNIT = Range(0.0, 1.0)
"""A share: 0 to 1."""


class Settings:
    """Base of the settings dataclasses (declare them ``@dataclass(frozen=True)``): checked on creation."""

    KIND = "setting"
    """How error messages name one of these settings (e.g. ``GA setting``)."""

    def __post_init__(self):
        for f, hint in _hints(type(self)).items():
            value = _checked(hint, getattr(self, f), f"{self.KIND} {f}")
            object.__setattr__(self, f, value)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def updated(self, **overrides):
        """A copy with ``overrides``; unknown names are a ``UserError`` listing the known ones."""
        unknown = sorted(set(overrides) - set(self.names()))
        if unknown:
            raise UserError(f"unknown {self.KIND}(s) {', '.join(unknown)} (known: {', '.join(sorted(self.names()))})")
        return replace(self, **overrides)


@lru_cache(maxsize=None)
def _hints(cls) -> dict:
    hints = typing.get_type_hints(cls, include_extras=True)
    return {f.name: hints[f.name] for f in fields(cls)}


def _checked(hint, value, name: str):
    """``value`` as ``hint`` wants it (lists to tuples), or a ``UserError`` naming ``name``."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is typing.Annotated:
        value = _checked(args[0], value, name)
        for rule in args[1:]:
            if isinstance(rule, Range) and value is not None and not rule.holds(value):
                raise UserError(f"{name} must be {rule}, got {value!r}")
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _checked(inner[0], value, name)
    if origin is typing.Literal:
        if value not in args:
            raise UserError(f"unknown {name.split(' ')[-1]} {value!r} (known: {', '.join(map(str, args))})")
        return value
    if origin is tuple:
        if not isinstance(value, (tuple, list)):
            raise UserError(f"{name} must be a list, got {value!r}")
        item = args[0]
        return tuple(_checked(item, v, name) if item is not float else float(_checked(item, v, name))
                     for v in value)
    if hint is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise UserError(f"{name} must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise UserError(f"{name} must be an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value):
            raise UserError(f"{name} must be a finite number, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise UserError(f"{name} must be a string, got {value!r}")
        return value
    return value
