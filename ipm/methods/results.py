"""The one writer of a method's result folder, ours and the baselines'.

Every folder has mesh.ply (world frame) and timing.json; a procedural method's mesh is part-labelled
(its labels in mesh.ply, and mesh.glb) and comes with params.json and trace.csv; a baseline's
geometry alone comes with info.json.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from ipm.generators.base import Mesh
from ipm.io import atomic_dir, write_json
from ipm.io.views import save_texture, srgb_bytes

GLB_EXTRAS = ("generator", "params", "pose")
"""Keys of params.json that the glTF file carries too (its ``extras``), where present."""


def write_result(out: str | Path, mesh: Mesh | tuple[np.ndarray, np.ndarray], info: dict, timing: dict,
                 trace: pd.DataFrame | None = None, info_file: str = "params.json",
                 extra_files: dict[str, Callable[[Path], None]] | None = None, failed: bool = False,
                 textures: dict[int, np.ndarray] | None = None) -> dict:
    """``mesh`` (a generator's part-labelled :class:`~ipm.generators.base.Mesh`, or a baseline's
    ``(vertices, faces)``), ``info`` as ``info_file``, ``trace`` as trace.csv, ``timing`` as
    timing.json (``seconds`` first, then the trace's length as ``evaluations``, then the rest) and
    each of ``extra_files`` (name -> writer of that path) in ``out``, atomically; a labelled mesh's
    ``textures`` (part index -> linear albedo (res, res, 3), ``ipm.texture``) go into mesh.glb and
    beside it as textures/PART.png. A mesh that is empty or not finite is a
    ``FloatingPointError``, unless the run ``failed`` (an empty mesh recorded with its reason).
    Returns ``info``."""
    labelled = isinstance(mesh, Mesh)
    vertices, faces = (mesh.vertices, mesh.faces) if labelled else mesh
    if not failed and (len(faces) == 0 or not np.all(np.isfinite(vertices))):
        raise FloatingPointError("the method produced an empty or non-finite mesh")
    times = {"seconds": timing["seconds"], **({"evaluations": int(len(trace))} if trace is not None else {}),
             **{k: v for k, v in timing.items() if k != "seconds"}}
    from ipm.io.mesh import save_glb, save_ply  # trimesh: only where a result is written

    with atomic_dir(out) as tmp:
        save_ply(tmp / "mesh.ply", vertices, faces, mesh.labels if labelled else None)
        if labelled:
            images = {k: srgb_bytes(t) for k, t in (textures or {}).items()}
            save_glb(tmp / "mesh.glb", mesh.vertices, mesh.faces, mesh.labels, mesh.part_names, mesh.uv,
                     normals=mesh.normals, extras={k: info[k] for k in GLB_EXTRAS if k in info}, textures=images)
            for k, image in images.items():
                save_texture(tmp / TEXTURES / f"{mesh.part_names[k]}.png", image)
        write_json(tmp / info_file, info)
        if labelled and not failed and "generator" in info and "params" in info:
            _write_city_model(tmp, info)
        if trace is not None:
            trace.to_csv(tmp / "trace.csv", index=False)
        write_json(tmp / "timing.json", times)
        for name, write in (extra_files or {}).items():
            write(tmp / name)
    return info


def write_painted(out: str | Path, generator, mesh: Mesh, info: dict, seconds: float, trace: pd.DataFrame,
                  views=None, timing: dict | None = None) -> dict:
    """A generator's fit written by :func:`write_result`, first painted from its input ``views``
    (``ipm.texture.dress``; unpainted without colour images): the texture record in ``info``, the
    stage's seconds in the fit's ``seconds`` and apart as ``texture_seconds`` (``timing``: more
    figures for timing.json)."""
    from ipm.texture import dress

    textures, record, texture_seconds = dress(generator, mesh, views)
    info = {**info, **record}
    times = {"seconds": seconds + texture_seconds, **(timing or {}),
             **({"texture_seconds": texture_seconds} if textures else {})}
    return write_result(out, mesh, info, times, trace, textures=textures)


TEXTURES = "textures"
"""A textured result's folder of part textures (PART.png, sRGB)."""
CITY_MODEL = "building.city.json"


def _write_city_model(folder: Path, info: dict) -> None:
    """The result's CityJSON city model beside its mesh, where its generator makes one (buildings)."""
    from ipm.generators import get_generator
    from ipm.io.cityjson import write_city_json

    gen = get_generator(info["generator"])
    doc = gen.city_model(gen.spec.from_dict(info["params"]))
    if doc is not None:
        write_city_json(folder / CITY_MODEL, doc)
