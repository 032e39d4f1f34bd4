"""Paths as the files we write name them: never the absolute folders of the machine that ran."""
from __future__ import annotations

import os
from pathlib import Path


def shown_path(path: str | os.PathLike, base: str | os.PathLike | None = None) -> str:
    """``path`` for an output file, a table or a report: a relative path as given; an absolute one
    relative to ``base`` (if given) or else to the working directory when it lies inside, otherwise
    its bare file name."""
    path = Path(path)
    if not path.is_absolute():
        return str(path)
    for folder in (base, os.getcwd()):
        if folder is None:
            continue
        try:
            return str(path.relative_to(Path(folder).absolute()))
        except ValueError:
            continue
    return path.name
