"""The one writer of a procedural method's result folder: mesh.ply, mesh.glb, params.json, trace.csv, timing.json."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ipm.generators.base import Mesh
from ipm.io import atomic_dir, save_glb, save_ply, write_json

GLB_EXTRAS = ("generator", "params", "pose")
"""Keys of params.json that the glTF file carries too (its ``extras``), where present."""


def write_result(out: str | Path, mesh: Mesh, info: dict, trace: pd.DataFrame, timing: dict) -> dict:
    """``mesh`` (world frame, part-labelled), ``info`` as params.json, ``trace`` as trace.csv and
    ``timing`` (``seconds`` at least; the trace's length is added as ``evaluations``) in ``out``,
    atomically; ``FloatingPointError`` for a mesh that is empty or not finite. Returns ``info``."""
    if not np.all(np.isfinite(mesh.vertices)) or len(mesh.faces) == 0:
        raise FloatingPointError("the reconstruction diverged (an empty or non-finite mesh)")
    with atomic_dir(out) as tmp:
        save_ply(tmp / "mesh.ply", mesh.vertices, mesh.faces, mesh.labels)
        save_glb(tmp / "mesh.glb", mesh.vertices, mesh.faces, mesh.labels, mesh.part_names, mesh.uv,
                 normals=mesh.normals, extras={k: info[k] for k in GLB_EXTRAS if k in info})
        write_json(tmp / "params.json", info)
        trace.to_csv(tmp / "trace.csv", index=False)
        write_json(tmp / "timing.json", {"seconds": timing["seconds"], "evaluations": int(len(trace)),
                                         **{k: v for k, v in timing.items() if k != "seconds"}})
    return info
