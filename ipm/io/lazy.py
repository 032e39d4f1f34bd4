"""A package's names loaded from its modules on first use (PEP 562), so that importing one module
of the package does not import what its siblings need."""
from __future__ import annotations

import sys
from importlib import import_module
from typing import Callable


def lazy_names(package: str, where: dict[str, str]) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for ``package`` whose names ``where`` maps to the module (relative
    to the package) each is defined in; a name is loaded once and then kept in the package."""

    def getattr_(name: str):
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(f"{package}.{where[name]}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def dir_() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return getattr_, dir_
