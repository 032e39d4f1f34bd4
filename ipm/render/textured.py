"""Colour renders with Mitsuba under the reference lighting (a dim constant environment and a
directional light, path traced): meshes wearing part textures (the references' materials,
``ipm.render.appearance``; the texture stage's shading, refinement and scores), part-coloured
previews, and a seeded high-frequency noise texture (the segmenter's training photographs and the
``photo`` layout's textured cases).
"""
from __future__ import annotations

import numpy as np

from ipm.render.cameras import sensor_dict


def procedural_texture(seed: int, size: int = 512) -> np.ndarray:
    """A colourful multi-scale noise texture (size, size, 3) in [0, 1]: SIFT-friendly, no download."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size, size, 3))
    for cell, weight in ((64, 0.35), (16, 0.35), (4, 0.3)):
        n = size // cell
        coarse = rng.random((n, n, 3))
        tex += weight * np.kron(coarse, np.ones((cell, cell, 1)))
    return np.clip(tex, 0.0, 1.0)


def unweld(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray):
    """One vertex per face corner with its corner's UV (``uv`` (F, 3, 2), ``ipm.uv``)."""
    return vertices[faces].reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3), np.asarray(uv).reshape(-1, 2)


PART_COLOURS = np.array([[0.75, 0.75, 0.78], [0.85, 0.35, 0.15], [0.2, 0.55, 0.25], [0.2, 0.35, 0.8],
                         [0.8, 0.7, 0.2], [0.6, 0.3, 0.7]])
"""Diffuse colour of part label k (body grey, handle orange, ...), cycling beyond six parts."""


def render_parts(vertices, faces, labels, c2w: np.ndarray, fov_x: float, width: int, height: int,
                 spp: int = 32) -> np.ndarray:
    """Linear RGB renders (n, height, width, 3) with one flat colour per part label."""
    import mitsuba as mi

    faces = np.asarray(faces)
    v = np.asarray(vertices)[faces].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    labels = np.zeros(len(faces), int) if labels is None else np.asarray(labels)
    colours = np.repeat(PART_COLOURS[labels % len(PART_COLOURS)], 3, axis=0)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "mesh_attribute",
                                                                     "name": "vertex_color"}})
    mesh = mi.Mesh("object", len(v), len(f), props=props)
    mesh.add_attribute("vertex_color", 3, mi.Float(colours.astype(np.float32).ravel()))
    return _render_lit(mesh, v, f, c2w, fov_x, width, height, spp)


def _render_lit(mesh, v, f, c2w, fov_x, width, height, spp):
    """Set the mesh buffers and render it under the reference lighting from each camera."""
    set_mesh_buffers(mesh, v, f)
    return _render_scene({"object": mesh}, c2w, fov_x, width, height, spp)


def set_mesh_buffers(mesh, v, f) -> None:
    """Give a Mitsuba mesh its vertex positions (V, 3) and faces (F, 3)."""
    import mitsuba as mi

    mp = mi.traverse(mesh)
    mp["vertex_positions"] = mi.Float(np.asarray(v, np.float32).ravel())
    mp["faces"] = mi.UInt32(np.asarray(f, np.uint32).ravel())
    mp.update()


def lit_scene(shapes: dict, c2w, fov_x, width, height, integrator: str = "path"):
    """A Mitsuba scene of ``shapes`` (name -> Mitsuba shape) under the reference lighting (a dim
    constant sky and a sun) with a sensor per camera; ``integrator`` path (rendering) or prb
    (differentiable in the materials), three bounces."""
    lights = {"env": {"type": "constant", "radiance": {"type": "rgb", "value": 0.35}},
              "sun": {"type": "directional", "direction": [-0.4, -1.0, -0.3],
                      "irradiance": {"type": "rgb", "value": 2.5}}}
    return _scene({"type": integrator, "max_depth": 3}, shapes, lights, c2w, fov_x, width, height)


def _scene(integrator: dict, shapes: dict, lights: dict, c2w, fov_x, width, height):
    """A Mitsuba scene of ``shapes`` and ``lights`` with ``integrator`` and a sensor per camera."""
    import mitsuba as mi

    scene = {"type": "scene", "integrator": integrator, **shapes, **lights}
    for i, m in enumerate(c2w):
        scene[f"sensor_{i:03d}"] = sensor_dict(m, fov_x, width, height)
    return mi.load_dict(scene)


def _render_all(scene, n: int, spp: int) -> np.ndarray:
    """The scene's images from each of its ``n`` sensors (n, H, W, channels), seeded by the sensor."""
    import mitsuba as mi

    return np.stack([np.array(mi.render(scene, sensor=i, spp=spp, seed=i)) for i in range(n)])


def _render_scene(shapes: dict, c2w, fov_x, width, height, spp):
    """Render ``shapes`` (name -> Mitsuba shape) under the reference lighting from each camera."""
    return _render_all(lit_scene(shapes, c2w, fov_x, width, height), len(c2w), spp)


def render_painted(vertices, faces, labels, uv, textures: dict, c2w: np.ndarray, fov_x: float, width: int,
                   height: int, spp: int = 64) -> np.ndarray:
    """Linear RGB renders (n, height, width, 3) under the reference lighting of a mesh whose part
    k wears ``textures[k]`` (res, res, 3) linear albedo on its UVs (``uv`` (F, 3, 2)); a part
    without one is white (the renders are then its shading)."""
    return _render_scene(painted_shapes(vertices, faces, labels, uv, textures), c2w, fov_x, width, height, spp)


def render_albedo(vertices, faces, labels, uv, textures: dict, c2w: np.ndarray, fov_x: float, width: int,
                  height: int, spp: int = 16) -> np.ndarray:
    """The albedo (n, height, width, 3) each pixel sees first, filtered over the pixel as
    :func:`render_painted` filters its radiance (Mitsuba's ``aov`` integrator; 0 off the mesh)."""
    scene = _scene({"type": "aov", "aovs": "albedo:albedo"}, painted_shapes(vertices, faces, labels, uv, textures),
                   {}, c2w, fov_x, width, height)
    return _render_all(scene, len(c2w), spp)


def render_glb(path, c2w: np.ndarray, fov_x: float, width: int, height: int, spp: int = 64) -> np.ndarray:
    """:func:`render_painted` of a textured glb (``ipm.io.mesh.read_textured_glb``): its parts in
    their textures under the reference lighting from each camera."""
    from ipm.io.mesh import read_textured_glb

    vertices, faces, labels, uv, textures = read_textured_glb(path)
    return render_painted(vertices, faces, labels, uv, textures, c2w, fov_x, width, height, spp)


def painted_shapes(vertices, faces, labels, uv, textures: dict) -> dict:
    """Mitsuba meshes ``part_K`` of a part-labelled mesh, part k wearing ``textures[k]`` (see
    :func:`render_painted`; white without one). A texture is an image as glTF reads one (its first
    row at v = 1); Mitsuba's bitmap puts its first row at v = 0, so it gets it upside down: its
    parameter ``part_K.bsdf.reflectance.data`` holds it so."""
    import mitsuba as mi

    faces, labels = np.asarray(faces), np.asarray(labels)
    shapes = {}
    for k in np.unique(labels):
        sel = labels == k
        v, f, t = unweld(np.asarray(vertices), faces[sel], np.asarray(uv)[sel])
        texture = textures.get(int(k))
        props = _bsdf_props(texture[::-1]) if texture is not None else mi.Properties()
        if texture is None:
            props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": 1.0}})
        mesh = mi.Mesh(f"part_{k}", len(v), len(f), has_vertex_texcoords=True, props=props)
        mi.traverse(mesh)["vertex_texcoords"] = mi.Float(t.astype(np.float32).ravel())
        set_mesh_buffers(mesh, v, f)
        shapes[f"part_{k}"] = mesh
    return shapes


def _bsdf_props(texture: np.ndarray):
    import mitsuba as mi

    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {
        "type": "bitmap", "bitmap": mi.Bitmap(texture.astype(np.float32)), "filter_type": "bilinear",
        "wrap_mode": "repeat", "raw": True}})
    return props
