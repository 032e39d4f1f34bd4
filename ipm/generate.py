"""``ipm generate``: parameters back to a mesh at any level of detail, for artists.

The paper promises new levels of detail from the estimated parameters: a reconstruction's
``params.json`` (or a hand-edited one, or a flat ``{name: value}`` file) regenerates the object
at every level its generator has, in its own frame (upright on y = 0) or, with ``world``, where
the reconstruction placed it. The GLB keeps one node and one material per part, vertex normals,
and the generator's name and parameters in the scene's ``extras``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ipm.errors import UserError

POSE_KEYS = ("yaw", "tilt_x", "tilt_z", "translation", "scale")


def read_params(path: str | Path, generator: str) -> tuple[np.ndarray, dict | None]:
    """Physical parameter vector and pose (None if absent) from ``path`` for ``generator``;
    parameters not named keep the generator's defaults."""
    from ipm.generators import get_generator

    gen = get_generator(generator)
    path = Path(path)
    if not path.is_file():
        raise UserError(f"parameter file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"malformed parameter file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object of parameters")
    if data.get("generator", generator) != generator:
        raise UserError(f"{path} holds parameters of {data['generator']!r}, not {generator!r}")
    values = data.get("params", data if "pose" not in data else {})
    values = {k: v for k, v in values.items() if k != "generator"}
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values.values()):
        raise UserError(f"{path}: every parameter must be a number")
    x = gen.spec.from_dict(values)
    outside = [n for n, v, lo, hi in zip(gen.spec.names, x, gen.spec.lower, gen.spec.upper) if not lo <= v <= hi]
    if outside:
        raise UserError(f"{path}: outside the generator's bounds: {', '.join(outside)}")
    pose = data.get("pose")
    if pose is not None and not (isinstance(pose, dict) and set(POSE_KEYS) <= set(pose)):
        raise UserError(f"{path}: pose needs {', '.join(POSE_KEYS)}")
    return x, pose


def posed(vertices: np.ndarray, pose: dict) -> np.ndarray:
    """World vertices ``s * R_y(yaw) R_x(tilt_x) R_z(tilt_z) v + t`` (the convention of params.json)."""
    from ipm.problem import _rotation

    rot = np.asarray(_rotation(pose["yaw"], pose["tilt_x"], pose["tilt_z"]), np.float64)
    t = np.asarray(pose["translation"], np.float64)
    if not (np.isfinite(rot).all() and np.isfinite(t).all() and t.shape == (3,) and np.isfinite(pose["scale"])
            and pose["scale"] > 0):
        raise UserError("pose: non-finite values, a translation that is not 3 numbers, or a scale <= 0")
    return float(pose["scale"]) * vertices @ rot.T + t


FORMATS = {".glb": "glb", ".ply": "ply", ".json": "cityjson"}


def generate(generator: str, params: str | Path, lod: int, out: str | Path, world: bool = False,
             fmt: str | None = None, textures: str | Path | None = None) -> dict:
    """Write the mesh of ``params`` at ``lod`` to ``out`` (atomically) as ``fmt`` (glb, ply, or
    cityjson: a building's LoD 2.2 city model; default: from the suffix), a glb wearing the part
    textures of the folder ``textures`` (a reconstruction's textures/); returns a summary."""
    from ipm.texture import read_textures

    from ipm.generators import get_generator
    from ipm.io import save_glb, save_ply

    gen = get_generator(generator)
    if lod not in gen.lods:
        raise UserError(f"{generator} has levels of detail {', '.join(map(str, gen.lods))}, not {lod}")
    suffix = Path(out).suffix.lower()
    fmt = fmt or FORMATS.get(suffix)
    if fmt not in FORMATS.values() or FORMATS.get(suffix) != fmt:
        raise UserError(f"--out must end in .glb, .ply or .json (cityjson), matching --format; got {out}")
    x, pose = read_params(params, generator)
    if textures is not None and fmt != "glb":
        raise UserError("--textures go into a glb: --out must end in .glb")
    images = read_textures(textures, gen.part_names) if textures is not None else None
    if fmt == "cityjson":
        return _city_json(gen, x, lod, out, world)
    mesh = gen.mesh(x, lod)
    vertices, normals = mesh.vertices, mesh.normals
    if world:
        if pose is None:
            raise UserError(f"{params} has no pose (--world needs a reconstruction's params.json)")
        vertices = posed(vertices, pose)
        normals = posed(normals, {**pose, "translation": [0.0, 0.0, 0.0], "scale": 1.0})
    if fmt == "glb":
        save_glb(out, vertices, mesh.faces, mesh.labels, mesh.part_names, mesh.uv, normals=normals,
                 extras={"generator": generator, "lod": lod, "params": gen.spec.as_dict(x),
                         **({"pose": pose} if world else {})}, textures=images)
    else:
        save_ply(out, vertices, mesh.faces, mesh.labels)
    parts = {name: int(np.sum(mesh.labels == k)) for k, name in enumerate(mesh.part_names)}
    return {"triangles": int(len(mesh.faces)), "parts": {k: v for k, v in parts.items() if v}}


def _city_json(gen, x: np.ndarray, lod: int, out: str | Path, world: bool) -> dict:
    """``gen``'s city model of ``x`` at level ``lod`` written to ``out``; a summary of its surfaces."""
    from ipm.io.cityjson import write_city_json

    if world:
        raise UserError("CityJSON is written in the building's own frame (metres, ground at z = 0): drop --world")
    doc = gen.city_model(x, lod)
    if doc is None:
        raise UserError(f"{gen.name} has no city model: CityJSON is written for buildings")
    write_city_json(out, doc)
    part = doc["CityObjects"]["building-part-0"]["geometry"][0]
    kinds = [s["type"] for s in part["semantics"]["surfaces"]]
    counts = {k: part["semantics"]["values"][0].count(i) for i, k in enumerate(kinds)}
    return {"surfaces": int(len(part["boundaries"][0])), "parts": counts}
