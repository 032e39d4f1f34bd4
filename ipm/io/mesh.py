"""Mesh files: PLY in the world frame, GLB with one named node per part, validated loading."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from ipm.errors import UserError
from ipm.io.atomic import atomic_path


def load_mesh(path: str | os.PathLike, allow_empty: bool = False) -> trimesh.Trimesh:
    """Load a triangle mesh (PLY/OBJ/GLB/...); raise ``UserError`` if missing, unreadable or non-finite."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"mesh file not found: {path}")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:
        raise UserError(f"cannot read mesh {path}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise UserError(f"{path} holds no triangle mesh")
    if len(mesh.faces) == 0 and not allow_empty:
        raise UserError(f"mesh {path} has no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise UserError(f"mesh {path} has NaN or infinite vertex coordinates")
    return mesh


def part_labels(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """The per-face ``part`` property of a mesh loaded from one of our PLY files (None if absent)."""
    face = mesh.metadata.get("_ply_raw", {}).get("face", {}).get("data")
    if face is None or getattr(face, "dtype", None) is None or "part" not in face.dtype.names:
        return None
    return np.asarray(face["part"], np.int32)


def save_ply(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
             labels: np.ndarray | None = None) -> None:
    """Write a binary PLY atomically; ``labels`` (one int per face) go in a ``part`` face property."""
    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)
    if labels is not None:
        mesh.face_attributes["part"] = np.asarray(labels, np.int32)
    with atomic_path(path) as tmp:
        tmp.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary", include_attributes=True))


PART_COLOURS = ((0.80, 0.78, 0.74), (0.35, 0.55, 0.75), (0.45, 0.33, 0.22), (0.62, 0.25, 0.20),
                (0.30, 0.20, 0.12), (0.55, 0.55, 0.58), (0.25, 0.55, 0.22), (0.70, 0.65, 0.30))
"""Base colours of the parts' materials, by part index (repeating)."""


def weld(faces: np.ndarray, corner_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One vertex per distinct (vertex, UV) pair: the source vertex of each (W,), the faces over them
    (F, 3) and their UVs (W, 2)."""
    faces = np.asarray(faces)
    key = np.concatenate([faces.reshape(-1, 1),
                          np.round(np.asarray(corner_uv).reshape(-1, 2) * (1 << 24)).astype(np.int64)], 1)
    unique, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return unique[:, 0], inverse.reshape(faces.shape), np.asarray(corner_uv).reshape(-1, 2)[first]


def save_glb(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
             part_names: tuple[str, ...], uv: np.ndarray | None = None, normals: np.ndarray | None = None,
             extras: dict | None = None, textures: dict | None = None) -> None:
    """Write a GLB atomically: one named node and one named material per part present (e.g.
    ``body``, ``handle``), texture coordinates (``uv`` per triangle corner, (F, 3, 2)) and vertex
    normals if given, a part's ``textures[k]`` (an sRGB image, (res, res, 3) uint8) as its
    material's ``baseColorTexture`` (embedded PNG), ``extras`` (JSON) in the scene's extras."""
    vertices, faces, labels = np.asarray(vertices), np.asarray(faces), np.asarray(labels)
    scene = trimesh.Scene()
    for k, name in enumerate(part_names):
        sel = faces[labels == k]
        if len(sel) == 0:
            continue
        if uv is None:
            used, inv = np.unique(sel, return_inverse=True)
            uv_part = None
        else:
            used, inv, uv_part = weld(sel, np.asarray(uv)[labels == k])
        image = None if textures is None or k not in textures else Image.fromarray(np.asarray(textures[k], np.uint8))
        colour = [1.0, 1.0, 1.0, 1.0] if image is not None else [*PART_COLOURS[k % len(PART_COLOURS)], 1.0]
        material = trimesh.visual.material.PBRMaterial(name=name, baseColorFactor=colour, metallicFactor=0.0,
                                                       roughnessFactor=0.8, baseColorTexture=image)
        visual = trimesh.visual.TextureVisuals(uv=uv_part, material=material)
        part = trimesh.Trimesh(vertices[used], inv.reshape(-1, 3), visual=visual, process=False,
                               vertex_normals=None if normals is None else np.asarray(normals)[used])
        scene.add_geometry(part, node_name=name, geom_name=name)
    if extras:
        scene.metadata.update(extras)
    with atomic_path(path) as tmp:
        tmp.write_bytes(scene.export(file_type="glb", include_normals=normals is not None))


def read_textured_glb(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """A textured glb's vertices, faces, part labels (by node order), per-corner UVs and part
    textures {label: linear albedo (h, w, 3)} (``UserError`` where a part has no texture)."""
    from ipm.io.views import linear_from_srgb

    path = Path(path)
    if not path.is_file():
        raise UserError(f"textured mesh not found: {path}")
    scene = trimesh.load(path, force="scene")
    vertices, faces, labels, uv, textures, offset = [], [], [], [], {}, 0
    for k, (name, part) in enumerate(scene.geometry.items()):
        image = getattr(part.visual.material, "baseColorTexture", None)
        if getattr(part.visual, "uv", None) is None or image is None:
            raise UserError(f"{path}: part {name!r} has no texture")
        vertices.append(np.asarray(part.vertices))
        faces.append(np.asarray(part.faces) + offset)
        labels.append(np.full(len(part.faces), k))
        uv.append(np.asarray(part.visual.uv)[np.asarray(part.faces)])
        textures[k] = linear_from_srgb(np.asarray(image.convert("RGB"), np.float64) / 255.0)
        offset += len(part.vertices)
    return np.concatenate(vertices), np.concatenate(faces), np.concatenate(labels), np.concatenate(uv), textures
