"""The report's per-run gallery (the paper's Figures 7-9): a mesh from three fixed novel views,
shaded (top row, Mitsuba, one colour per part) and as a wireframe of its visible edges (bottom
row), framed by the case's *reference* so that every method of a case is seen the same way.

The wireframe is exact hidden-line removal by ray casting (open3d, as the metrics): every edge is
sampled every half pixel and a sample is drawn where the ray from the camera to it hits nothing
nearer, over a light-grey fill of the mesh's silhouette. A missing, empty or unreadable mesh gives
a sheet of the same size that says so.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ipm.render.cameras import orbit_camera, project

VIEWS = ((75.0, 15.0), (195.0, 25.0), (315.0, -20.0))
"""(azimuth, elevation) in degrees of the three novel views, about +y from +z: none is an input
view (hemi1's camera sits at about (13, 30)); the last one looks from below, which no input sees."""
FOV_DEG = 40.0
"""Horizontal field of view of the gallery cameras."""
MARGIN = 1.1
"""The reference's bounding box fills 1 / MARGIN of each view (its widest corner)."""
PAPER, FILL, INK = 1.0, 0.78, 0.02
"""Linear grey levels of the wireframe's background, silhouette fill and edges."""


def gallery_cameras(reference: trimesh.Trimesh) -> np.ndarray:
    """OpenGL camera-to-world matrices (3, 4, 4) of :data:`VIEWS`, each looking at the centre of
    ``reference``'s bounding box from the distance where the box just fits (with :data:`MARGIN`)."""
    lo, hi = reference.bounds
    centre = (lo + hi) / 2.0
    corners = np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, 3) - centre
    tan = np.tan(np.radians(FOV_DEG) / 2.0)
    cameras = []
    for az, el in VIEWS:
        axes = orbit_camera(centre, 1.0, az, el)[:3, :3]  # columns: right, up, back
        right, up, back = (corners @ axes).T
        distance = float(np.max(back + MARGIN * np.maximum(np.abs(right), np.abs(up)) / tan))
        cameras.append(orbit_camera(centre, distance, az, el))
    return np.stack(cameras)


def _edge_samples(vertices: np.ndarray, edges: np.ndarray, c2w: np.ndarray, res: int, step: float = 0.5):
    """World points every ``step`` pixels along each edge seen in front of the camera, their
    pixel positions and the pixel length each stands for."""
    fov = np.radians(FOV_DEG)
    w2c = np.linalg.inv(c2w)
    depth = -(vertices @ w2c[2, :3] + w2c[2, 3])
    front = (depth[edges] > 1e-6).all(1)
    edges = edges[front]
    px = project(vertices, c2w, fov, res, res)
    length = np.linalg.norm(px[edges[:, 1]] - px[edges[:, 0]], axis=1)
    n = np.minimum(np.ceil(length / step).astype(np.int64), 8 * res) + 1
    which = np.repeat(np.arange(len(edges)), n)
    first = np.cumsum(n) - n
    t = (np.arange(len(which)) - first[which]) / np.maximum(n[which] - 1, 1)
    a, b = vertices[edges[which, 0]], vertices[edges[which, 1]]
    points = a + t[:, None] * (b - a)
    return points, project(points, c2w, fov, res, res), (length / np.maximum(n - 1, 1))[which]


def _splat(xy: np.ndarray, weight: np.ndarray, res: int) -> np.ndarray:
    """Bilinear splat of weighted points (pixel coordinates, centres at +0.5) into a (res, res) image."""
    x, y = xy[:, 0] - 0.5, xy[:, 1] - 0.5
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    acc = np.zeros((res + 2, res + 2))
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        xi, yi = np.clip(x0 + dx + 1, 0, res + 1), np.clip(y0 + dy + 1, 0, res + 1)
        np.add.at(acc, (yi, xi), w * weight)
    return acc[1:-1, 1:-1]


def wireframe(mesh: trimesh.Trimesh, cameras: np.ndarray, res: int) -> np.ndarray:
    """Linear grey images (n, res, res) of the visible edges of ``mesh`` over its silhouette."""
    from ipm.metrics.silhouette import camera_rays, raycasting_scene

    scene = raycasting_scene(mesh)
    vertices = np.asarray(mesh.vertices, np.float64)
    eps = 1e-3 * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    out = []
    for c2w, eye, d in zip(cameras, *camera_rays(cameras, res, FOV_DEG)):
        rays = np.concatenate([np.broadcast_to(eye, d.shape), d], 1).astype(np.float32)
        hit = np.isfinite(scene.cast_rays(rays)["t_hit"].numpy()).reshape(res, res)
        points, xy, weight = _edge_samples(vertices, mesh.edges_unique, c2w, res)
        inside = ((xy >= 0) & (xy < res)).all(1)
        points, xy, weight = points[inside], xy[inside], weight[inside]
        to = points - eye
        dist = np.linalg.norm(to, axis=1)
        rays = np.concatenate([np.broadcast_to(eye, to.shape), to / dist[:, None]], 1).astype(np.float32)
        t_hit = scene.cast_rays(rays)["t_hit"].numpy()
        seen = t_hit >= dist - eps
        ink = 1.0 - np.exp(-1.5 * _splat(xy[seen], weight[seen], res))  # one edge: 0.8, dense: 1
        base = np.where(hit, FILL, PAPER)
        out.append(base + (INK - base) * ink)
    return np.stack(out)


def _placeholder(text: str, width: int, height: int) -> np.ndarray:
    """A dark (height, width, 3) linear RGB image with ``text`` across its middle."""
    from PIL import Image, ImageDraw, ImageFont

    img = Image.new("L", (width, height), 0)
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default(size=max(10, height // 16))
    draw.text((width / 2, height / 2), text, fill=255, font=font, anchor="mm")
    tile = 0.04 + 0.75 * np.asarray(img, np.float64) / 255.0
    return np.repeat(tile[..., None], 3, axis=2)


def _load(path: str) -> tuple[trimesh.Trimesh | None, str]:
    """The mesh at ``path`` with at least one triangle, or None and why not."""
    from ipm.errors import UserError
    from ipm.io import load_mesh

    if not Path(path).is_file():
        return None, "no mesh (the run wrote none)"
    try:
        mesh = load_mesh(path, allow_empty=True)
    except UserError as exc:  # unreadable, or NaN vertices
        return None, str(exc).replace(str(path), Path(path).name)
    if len(mesh.faces) == 0:
        return None, "empty mesh (0 triangles)"
    return mesh, ""


def gallery_sheet(mesh: str, reference: str, out_png: str, res: int = 160, spp: int = 16) -> None:
    """Write ``out_png`` (2 res x 3 res pixels), atomically: ``mesh`` from the three views of
    :func:`gallery_cameras` of ``reference``, shaded with one colour per part, or wearing its
    textures under the reference lighting where its folder holds a textured result (mesh.glb and
    textures/) (top), and as the wireframe of its visible edges (bottom); a missing, empty or
    unreadable mesh gives a sheet of the same size that says so. Needs a Mitsuba variant set
    (``ipm.runtime.set_mitsuba_variant``)."""
    from ipm.io import load_mesh, part_labels
    from ipm.io.views import save_rgb
    from ipm.render.textured import render_glb, render_parts

    cameras = gallery_cameras(load_mesh(reference))
    m, why = _load(mesh)
    if m is None:
        save_rgb(out_png, _placeholder(why, len(cameras) * res, 2 * res))
        return
    glb = Path(mesh).with_name("mesh.glb")
    if glb.is_file() and (glb.parent / "textures").is_dir():
        shaded = render_glb(glb, cameras, np.radians(FOV_DEG), res, res, spp)
    else:
        shaded = render_parts(m.vertices, m.faces, part_labels(m), cameras, np.radians(FOV_DEG), res, res, spp)
    shaded = np.nan_to_num(shaded, nan=0.0)  # degenerate triangles (a convex hull's slivers) give NaN samples
    lines = np.repeat(wireframe(m, cameras, res)[..., None], 3, axis=3)
    save_rgb(out_png, np.concatenate([np.concatenate(list(r), axis=1) for r in (shaded, lines)], axis=0))
