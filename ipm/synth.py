"""Synthetic references: a case (generator + ground truth, or a foreign recipe) -> rendered views.

``ipm synth --case CASE --out DIR`` writes DIR/transforms.json, DIR/rgb/, DIR/masks/,
DIR/reference.ply and DIR/ground_truth.json. View 0 is the single input view (15-30 deg
elevation); further views lie on a Fibonacci hemisphere around the object.
"""
from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np
import trimesh

from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.io import atomic_dir, save_ply, write_json
from ipm.io.views import save_mask, save_rgb, write_views
from ipm.registry import Registry
from ipm.render.cameras import orbit_camera

RECIPES: Registry = Registry("mesh recipe")
FOV_X = 0.6911
"""Horizontal field of view of the reference cameras (radians), as in instant-ngp's examples."""


def list_cases() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("datasets_synthetic").iterdir()
                  if p.name.endswith(".json"))


def load_case(name: str) -> dict:
    """The case definition ``datasets_synthetic/NAME.json`` (``UserError`` if unknown)."""
    path = resources.files("datasets_synthetic") / f"{name}.json"
    if not path.is_file():
        raise UserError(f"unknown case {name!r} (known: {', '.join(list_cases())})")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"malformed case file {name}.json: {exc}") from None


def _cylindrical_uv(vertices: np.ndarray) -> np.ndarray:
    """UVs for meshes that have none: angle about +y and height."""
    u = (np.arctan2(vertices[:, 2], vertices[:, 0]) / (2 * np.pi)) % 1.0
    y = vertices[:, 1]
    return np.stack([u, (y - y.min()) / max(np.ptp(y), 1e-9)], 1)


@RECIPES.register("footed_cup")
def footed_cup(radius_bottom, radius_top, height, wall, foot_radius, foot_height,
               handle_reach, handle_low, handle_high, handle_radius, sections=96):
    """A cup on a foot ring with a three-bar handle: trimesh primitives, no dishes-generator code."""
    r0, r1, h = radius_bottom, radius_top, height
    prof = [[0.0, 0.0], [foot_radius, 0.0], [foot_radius, foot_height], [r0, foot_height + 0.01]]
    prof += [[r0 + (r1 - r0) * s ** 1.5, foot_height + 0.01 + (h - foot_height - 0.01) * s]
             for s in np.linspace(0.1, 1.0, 12)]
    prof += [[r1 - wall, h]]
    prof += [[r0 - wall + (r1 - r0) * s ** 1.5, foot_height + 0.04 + (h - foot_height - 0.04) * s]
             for s in np.linspace(0.95, 0.0, 12)]
    prof += [[0.0, foot_height + 0.04]]
    body = trimesh.creation.revolve(np.array(prof)[::-1], sections=sections)
    body.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))

    def radius_at(y):
        s = np.clip((y - foot_height - 0.01) / (h - foot_height - 0.01), 0, 1)
        return r0 + (r1 - r0) * s ** 1.5

    y_lo, y_hi = handle_low * h, handle_high * h
    x_lo, x_hi = radius_at(y_lo) - wall / 2, radius_at(y_hi) - wall / 2
    x_out = max(x_lo, x_hi) + handle_reach
    bars = [((x_lo, y_lo), (x_out, y_lo)), ((x_out, y_lo), (x_out, y_hi)), ((x_hi, y_hi), (x_out, y_hi))]
    parts = [body]
    for (a, b) in bars:
        parts.append(trimesh.creation.cylinder(radius=handle_radius, segment=[[a[0], a[1], 0], [b[0], b[1], 0]],
                                               sections=24))
    for corner in ((x_out, y_lo), (x_out, y_hi)):
        parts.append(trimesh.creation.icosphere(2, handle_radius).apply_translation([corner[0], corner[1], 0]))
    for p in parts:
        trimesh.repair.fix_normals(p)  # outward winding: Mitsuba's area emitters are one-sided
    labels = np.concatenate([np.full(len(p.faces), 0 if i == 0 else 1) for i, p in enumerate(parts)])
    mesh = trimesh.util.concatenate(parts)
    return mesh.vertices, mesh.faces, labels, _cylindrical_uv(mesh.vertices)


def ground_truth_mesh(case: dict, lod: int = 2):
    """World-frame vertices, faces, part labels and UVs of a case's ground truth."""
    src = case["source"]
    if "generator" in src:
        gen = get_generator(src["generator"])
        base = gen.presets[src["preset"]] if "preset" in src else None
        if "preset" in src and src["preset"] not in gen.presets:
            raise UserError(f"unknown preset {src['preset']!r}")
        x = gen.spec.from_dict(src.get("params", {}), base)
        m = gen.mesh(x, lod)
        v, f, labels, uv = m.vertices, m.faces, m.labels, m.uv
    else:
        v, f, labels, uv = RECIPES[src["recipe"]](**src.get("args", {}))
    pose = case.get("pose", {})
    rot = trimesh.transformations.rotation_matrix(np.radians(pose.get("yaw_deg", 0.0)), [0, 1, 0])[:3, :3]
    v = pose.get("scale", 1.0) * np.asarray(v) @ rot.T + np.asarray(pose.get("translation", [0, 0, 0]))
    return v, np.asarray(f), np.asarray(labels), np.asarray(uv)


def view_cameras(center: np.ndarray, radius: float, n_views: int, azimuth: float, elevation: float):
    """Camera 0 at (azimuth, elevation); others on a Fibonacci hemisphere (elevation 5..75 deg)."""
    dist = 1.3 * radius / np.sin(FOV_X / 2)
    cams = [orbit_camera(center, dist, azimuth, elevation)]
    golden = np.pi * (3 - np.sqrt(5))
    for i in range(1, n_views):
        s = (i - 0.5) / max(n_views - 1, 1)
        el = 5.0 + 70.0 * s
        az = azimuth + np.degrees(golden * i)
        cams.append(orbit_camera(center, dist, az, el))
    return np.stack(cams)


def synthesize(case: str, out: str | Path, n_views: int = 1, res: int = 256, spp: int = 64,
               progress: bool = True) -> None:
    """Render the case's references into ``out`` (atomically: all or nothing)."""
    from tqdm import tqdm

    from ipm.render.silhouette import SilhouetteRenderer
    from ipm.render.textured import render_rgb

    if n_views < 1 or res < 16:
        raise UserError("need at least 1 view and 16 px")
    spec = load_case(case)
    v, f, labels, uv = ground_truth_mesh(spec)
    lo, hi = v.min(0), v.max(0)
    center, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
    cam = spec.get("camera", {})
    c2w = view_cameras(center, radius, n_views, cam.get("azimuth_deg", 0.0), cam.get("elevation_deg", 22.0))
    with atomic_dir(out) as tmp:
        rgb = render_rgb(v, f, uv, c2w, FOV_X, res, res, spec.get("texture_seed", 0), spp)
        masks = SilhouetteRenderer(c2w, FOV_X, res, res, spp=16).render(v, f)
        frames = []
        for i in tqdm(range(n_views), desc=f"synth {case}", disable=not progress, leave=False):
            save_rgb(tmp / "rgb" / f"{i:03d}.png", rgb[i])
            save_mask(tmp / "masks" / f"{i:03d}.png", masks[i] > 0.5)
            frames.append({"file_path": f"rgb/{i:03d}.png", "mask_path": f"masks/{i:03d}.png",
                           "transform_matrix": c2w[i]})
        write_views(tmp / "transforms.json", FOV_X, res, res, frames)
        save_ply(tmp / "reference.ply", v, f, labels)
        write_json(tmp / "ground_truth.json", spec)
