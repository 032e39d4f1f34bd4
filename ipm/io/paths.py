"""Paths as the files we write name them: never the absolute folders of the machine that ran."""
from __future__ import annotations

import os
from pathlib import Path


def shown_path(path: str | os.PathLike) -> str:
    """``path`` for an output file, a table or a report: a relative path as given; an absolute one
    relative to the working directory when it lies inside, otherwise its bare file name."""
    path = Path(path)
    if not path.is_absolute():
        return str(path)
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return path.name
