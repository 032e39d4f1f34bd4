"""A case's ground truth from a mesh file made by any tool: glTF or GLB, OBJ, PLY, STL, OFF (what
trimesh reads), registered as the recipe ``mesh_file``, so a model made outside this project is a
benchmark case like the recipes' (its case file: ``"source": {"recipe": "mesh_file", "args":
{"path": "meshes/NAME.glb", "up": "z", "height": 0.9}}``; cups and buildings). Where the file
gives every part a base colour (on its UVs, or per vertex as a scan's PLY does), the references
wear it (:func:`file_textures`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from datasets_synthetic.recipes import RECIPES, _cylindrical_uv
from ipm.errors import UserError
from ipm.uv import corners_from_vertices

CASES_DIR = Path(__file__).resolve().parent
"""Relative paths are read from here (``datasets_synthetic/``)."""
UP_AXES = ("y", "z")


def _parts(path: str) -> list[trimesh.Trimesh]:
    """The triangle meshes of the file at ``path`` (relative to :data:`CASES_DIR`, or absolute) in
    its own frame (a scene's geometries placed by their nodes, in the order trimesh lists them);
    ``UserError`` for a file that is missing, unreadable or holds no triangles."""
    path = Path(path) if Path(path).is_absolute() else CASES_DIR / path
    if not path.is_file():
        raise UserError(f"mesh file not found: {path}")
    try:
        loaded = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many kinds for a file it cannot parse
        raise UserError(f"unreadable mesh file {path}: {exc}") from None
    if isinstance(loaded, trimesh.Scene):
        parts = loaded.dump(concatenate=False)
        for part in parts:  # trimesh's copy keeps a material's UVs, not its COLOR_0
            source = loaded.geometry.get(part.metadata.get("name"))
            kept = getattr(getattr(source, "visual", None), "vertex_attributes", {})
            if "color" in kept and getattr(part.visual, "kind", None) == "texture":
                part.visual.vertex_attributes["color"] = kept["color"]
    else:
        parts = [loaded]
    parts = [p for p in parts if isinstance(p, trimesh.Trimesh) and len(p.faces)]
    if not parts:
        raise UserError(f"mesh file {path} holds no triangles")
    return parts


@RECIPES.register("mesh_file")
def mesh_file(path: str, up: str = "y", height: float | None = None):
    """The mesh in ``path`` (relative to ``datasets_synthetic/``, or absolute) as a recipe gives
    it: y up (``up`` "z": a z-up file, as many tools write OBJ and STL, turned to y up), standing on
    y = 0 and centred on the y axis (its bounding box's middle), scaled to ``height`` units where
    given (else the file's units); one part label per geometry of a scene (:func:`_parts`' order);
    each part's faces wound outwards where it is closed. UVs per corner (F, 3, 2): a part's own where
    each of its vertices has one (as the file has them: its seams are its own), else the angle about
    +y and the height. The volumetric metrics assume closed parts."""
    if up not in UP_AXES:
        raise UserError(f"mesh_file: up must be one of {', '.join(UP_AXES)}, got {up!r}")
    if height is not None and not (isinstance(height, (int, float)) and np.isfinite(height) and height > 0):
        raise UserError(f"mesh_file: height must be a positive number, got {height!r}")
    parts = _parts(path)
    for p in parts:
        if p.is_watertight:
            trimesh.repair.fix_normals(p)  # outward winding: Mitsuba's area emitters are one-sided
    uv = [getattr(p.visual, "uv", None) for p in parts]
    vertices = np.concatenate([np.asarray(p.vertices, np.float64) for p in parts])
    if not np.isfinite(vertices).all():
        raise UserError(f"mesh file {path} has vertices that are NaN or infinite")
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])[:-1]
    faces = np.concatenate([np.asarray(p.faces) + o for p, o in zip(parts, offsets)])
    labels = np.concatenate([np.full(len(p.faces), k) for k, p in enumerate(parts)])
    if up == "z":
        vertices = vertices[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # (x, y, z) -> (x, z, -y)
    lo, hi = vertices.min(0), vertices.max(0)
    if hi[1] - lo[1] <= 0:
        raise UserError(f"mesh file {path} is flat along its up axis ({up})")
    vertices = vertices - np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    if height is not None:
        vertices *= height / (hi[1] - lo[1])
    about = corners_from_vertices(faces, _cylindrical_uv(vertices))  # u unwrapped across its seam
    own = [u is not None and len(u) == len(p.vertices) for u, p in zip(uv, parts)]
    corner = np.concatenate([np.asarray(uv[k], np.float64)[np.asarray(p.faces)] if own[k] else about[labels == k]
                             for k, p in enumerate(parts)])
    return vertices, faces, labels, corner


def _base_colour(part: trimesh.Trimesh, size: int) -> np.ndarray | None:
    """A part's base colour as a (size, size, 3) linear bitmap in glTF's rows (the first at v = 1,
    as ``ipm.render.appearance.bake``'s): its texture (sRGB, where the part has UVs) times its factor
    (linear), or the factor alone; None where the file gives the part neither."""
    from PIL import Image

    from ipm.io.views import linear_from_srgb

    material, uv = getattr(part.visual, "material", None), getattr(part.visual, "uv", None)
    if material is None:
        return None
    image = getattr(material, "baseColorTexture", None)
    image = getattr(material, "image", None) if image is None else image
    if uv is None or len(uv) != len(part.vertices):
        image = None  # a texture needs the part's UVs
    factor = getattr(material, "baseColorFactor", None)
    if image is None and factor is None:
        return None
    factor = np.ones(3) if factor is None else np.asarray(factor, np.float64)[:3] / 255.0  # trimesh keeps it in bytes
    if image is None:
        return np.broadcast_to(factor, (size, size, 3)).copy()
    rgb = np.asarray(image.convert("RGB").resize((size, size), Image.BILINEAR), np.float64) / 255.0
    return linear_from_srgb(rgb) * factor


def _vertex_colours(part: trimesh.Trimesh, linear: bool) -> np.ndarray | None:
    """A part's colours per vertex (V, 3), linear, as a scan's PLY (sRGB bytes) or a glTF's COLOR_0
    (``linear`` already, glTF's rule; beside a material, as trimesh keeps it, in the accessor's own
    type) gives them; None where the file gives none."""
    from ipm.io.views import linear_from_srgb

    visual = part.visual
    if getattr(visual, "kind", None) == "vertex":
        rgb = np.asarray(visual.vertex_colors)  # bytes
    else:
        rgb = np.asarray(getattr(visual, "vertex_attributes", {}).get("color", np.zeros((0, 3))))
    scale = np.iinfo(rgb.dtype).max if np.issubdtype(rgb.dtype, np.integer) else 1.0  # normalized integers
    rgb = rgb[:, :3].astype(np.float64) / scale
    if len(rgb) != len(part.vertices):
        return None
    return rgb if linear else linear_from_srgb(rgb)


def _baked(colours: np.ndarray, points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray,
           size: int) -> np.ndarray:
    """A part's ``colours`` at its vertices ``points`` (V, 3) as a bitmap on its corner UVs (the
    part's ``faces`` of the case's ``vertices``): each texel's surface point takes its three
    nearest vertices' colours, weighted by inverse distance."""
    from scipy.spatial import cKDTree

    from ipm.render.appearance import bake

    tree, k = cKDTree(points), min(3, len(points))

    def colour(at, normals):
        d, i = tree.query(at, k=k)
        d, i = d.reshape(len(at), k), i.reshape(len(at), k)
        w = 1.0 / np.maximum(d, 1e-9)
        return (colours[i] * w[..., None]).sum(1) / w.sum(1, keepdims=True)

    return bake(vertices, faces, corner_uv, colour, size)


def file_textures(path: str, mesh: tuple, size: int | None = None) -> dict | None:
    """The base colours of the mesh file at ``path``, one linear bitmap per part label
    (``ipm.synth.reference_appearance``): a part's texture and factor on its UVs, times its vertex
    colours (glTF's product) baked onto the case's UVs (``mesh``: the case's vertices, faces, labels
    and corner UVs, ``ipm.synth.ground_truth_mesh``'s, whose vertices are the file's in its order and
    whose UVs are a part's own where it has them); None unless every part has one of them."""
    from ipm.render.appearance import TEXTURE_SIZE

    size = size or TEXTURE_SIZE
    parts = _parts(path)
    colours = [_base_colour(p, size) for p in parts]
    linear = Path(path).suffix.lower() in (".gltf", ".glb")
    vertices, faces, labels, corner_uv = mesh
    first = np.cumsum([0] + [len(p.vertices) for p in parts])
    for k, part in enumerate(parts):
        per_vertex = _vertex_colours(part, linear)
        if per_vertex is not None:
            own = labels == k
            baked = _baked(per_vertex, vertices[first[k]:first[k + 1]], vertices, faces[own], corner_uv[own], size)
            colours[k] = baked if colours[k] is None else colours[k] * baked
    return None if any(c is None for c in colours) else dict(enumerate(colours))
