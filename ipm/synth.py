"""Synthetic references: a case (generator + ground truth, or a foreign recipe) -> rendered views.

``ipm synth --case CASE --out DIR`` writes DIR/transforms.json, DIR/rgb/, DIR/masks/,
DIR/reference.ply and DIR/ground_truth.json, and DIR/semantic/ label images for classes that have
them (trees: branch, foliage; buildings: wall, window, roof, door). In the ``hemi`` layout view 0 is the single
input view (15-30 deg elevation) and further views lie on a Fibonacci hemisphere; the ``ring``
layout (COLMAP) puts textured views on rings; the ``photo`` layout takes the ``hemi`` cameras and
renders photographs (``ipm.render.photo_scene``: sky, sun, the object's shadow on a ground, a
backdrop), written as JPEG, with the true masks beside them. All views share the world frame.
"""
from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np
import trimesh

from ipm.cases import load_case
from ipm.errors import UserError
from ipm.generators import get_generator
from ipm.io import atomic_dir, save_ply, write_json
from ipm.io.views import save_mask, save_rgb, write_views
from datasets_synthetic import city_recipes, mesh_files, more_recipes, tree_recipes  # noqa: F401  (register their recipes in RECIPES)
from datasets_synthetic.recipes import RECIPES
from ipm.render.cameras import is_fov_deg, orbit_camera
from ipm.uv import corners_from_vertices

FOV_X = 0.6911
"""Horizontal field of view of the reference cameras (radians), as in instant-ngp's examples,
unless the case gives its own (``camera.fov_deg``)."""


def case_fov(case: dict) -> float:
    """The horizontal field of view of a case's cameras (radians): its ``camera.fov_deg``, else
    :data:`FOV_X` (``UserError`` outside 1-170 degrees)."""
    deg = case.get("camera", {}).get("fov_deg")
    if deg is None:
        return FOV_X
    if not is_fov_deg(deg):
        raise UserError(f"case {case.get('name')!r}: camera.fov_deg must be 1-170 degrees, got {deg!r}")
    return float(np.radians(deg))


def semantic_scheme(case: dict) -> tuple[dict, np.ndarray] | None:
    """The label map of a case's semantic images and the label of each part of its ground truth
    (a generator's ``part_semantic``; a recipe's parts are its ``semantic_labels`` in order), or
    None for classes without semantic images (cups)."""
    src = case.get("source", {})
    if "generator" in src:
        gen = get_generator(src["generator"])
        return (gen.semantic_labels, np.asarray(gen.part_semantic)) if gen.semantic_labels else None
    names = getattr(RECIPES[src["recipe"]], "semantic_labels", None) if src.get("recipe") in RECIPES else None
    return (names, np.arange(1, len(names))) if names else None


def is_tree_case(case: dict) -> bool:
    """True for cases whose semantic images are the trees' (0 background, 1 branch, 2 foliage):
    their references are rendered in the part colours that ``labels_from_rgb`` reads."""
    from ipm.io.semantic import LABEL_NAMES

    scheme = semantic_scheme(case)
    return scheme is not None and scheme[0] == LABEL_NAMES


def ground_truth_mesh(case: dict, lod: int | None = None):
    """World-frame vertices, faces, part labels and UVs of a case's ground truth (a generator's
    case at ``lod``, by default the generator's ``reference_lod``)."""
    src = case["source"]
    if "generator" in src:
        gen = get_generator(src["generator"])
        if "preset" in src and src["preset"] not in gen.presets:
            raise UserError(f"unknown preset {src['preset']!r}")
        base = gen.presets[src["preset"]] if "preset" in src else None
        x = gen.spec.from_dict(src.get("params", {}), base)
        m = gen.mesh(x, gen.reference_lod if lod is None else lod)
        v, f, labels, uv = m.vertices, m.faces, m.labels, m.uv
    else:
        if src.get("recipe") == "mesh_file" and case.get("generator") == "trees":
            raise UserError(f"case {case.get('name')!r}: a tree cannot come from a mesh file (the GA reads "
                            "branch and foliage from the references' part colours)")
        v, f, labels, uv = RECIPES[src["recipe"]](**src.get("args", {}))
        uv = corners_from_vertices(f, uv) if np.ndim(uv) == 2 else uv  # one UV a vertex, or (F, 3, 2) a corner
    pose = case.get("pose", {})
    # R_y of ipm.pose.yaw_matrix by trimesh's axis-angle formula, kept: at some angles it rounds the
    # 1 on the y axis to 1 - 2**-53, and the ground truths stay exactly as they were made
    rot = trimesh.transformations.rotation_matrix(np.radians(pose.get("yaw_deg", 0.0)), [0, 1, 0])[:3, :3]
    v = pose.get("scale", 1.0) * np.asarray(v) @ rot.T + np.asarray(pose.get("translation", [0, 0, 0]))
    return v, np.asarray(f), np.asarray(labels), np.asarray(uv)


LAYOUTS = ("hemi", "ring", "photo", "held")
"""View layouts: ``hemi`` (view 0 is the input view, the rest on a Fibonacci hemisphere; the
diffSDF views and ours), ``ring`` (rings of at most 16 views, 22.5 degrees apart or closer,
so neighbouring images share enough texture for SIFT matching; the COLMAP views), ``photo``
(the ``hemi`` cameras, photograph-like images: :func:`photo_setting`) and ``held`` (view 0 the
input view, the rest the ``hemi`` hemisphere turned by half the golden angle: views between
those any row is given, for scoring appearance on views no row saw)."""
PHOTO_QUALITY = 88
"""JPEG quality of the ``photo`` layout's images."""


PHOTO_DISTORTION = (0.02, 0.06)
"""Range of the barrel distortion of the ``photo`` layout's distorted cases: the share by which
the frame's corners move towards the centre (a lens's quoted distortion, -2 % to -6 %: strong for
the suite's 40-degree lens, where the object's edge, nearer the centre, moves by under a pixel at
256 px; the corners of a 256 px frame by 3-8 px). OpenCV's ``k1`` is this share over the corner's
squared distance from the centre (normalised image coordinates), so it stays invertible at any
field of view."""


def photo_setting(case: str) -> dict:
    """How a case is photographed in the ``photo`` layout, fixed by its name: the backdrop
    (``ipm.render.photo_scene.BACKDROPS``), the scene's seed (the sun's direction, the ground's
    pattern), for half the cases a plain colour in place of the case's texture, and for a third a
    barrel lens (``distortion``: :data:`PHOTO_DISTORTION`; 0 for a pinhole)."""
    from ipm.render.photo_scene import BACKDROPS

    key = zlib.crc32(case.encode())
    rng = np.random.default_rng(key)
    plain = rng.uniform(0.05, 0.85, 3).round(3).tolist()
    distortion = round(float(rng.uniform(*PHOTO_DISTORTION)), 4)
    return {"backdrop": BACKDROPS[key % len(BACKDROPS)], "seed": key % 100_003,
            "plain": plain if (key >> 3) % 2 else None, "distortion": distortion if (key >> 5) % 3 == 0 else 0.0}


def view_cameras(center: np.ndarray, radius: float, n_views: int, azimuth: float, elevation: float,
                 layout: str = "hemi", fov_x: float = FOV_X):
    """Camera-to-world matrices of ``n_views`` views around the object in ``layout``, far enough
    that the bounding sphere fills the same share of a field of view ``fov_x`` at any lens."""
    dist = 1.3 * radius / np.sin(fov_x / 2)
    if layout in ("hemi", "photo", "held"):
        cams = [orbit_camera(center, dist, azimuth, elevation)]
        golden = np.degrees(np.pi * (3 - np.sqrt(5)))
        turn = golden / 2 if layout == "held" else 0.0
        for i in range(1, n_views):
            s = (i - 0.5) / max(n_views - 1, 1)
            cams.append(orbit_camera(center, dist, azimuth + golden * i + turn, 5.0 + 70.0 * s))
    elif layout == "ring":
        n_rings = -(-n_views // 16)
        elevations = np.linspace(15.0, 60.0, n_rings) if n_rings > 1 else [30.0]
        counts = np.diff(np.linspace(0, n_views, n_rings + 1).round().astype(int))
        cams = [orbit_camera(center, dist, azimuth + 360.0 * (j + 0.5 * (r % 2)) / k, el)
                for r, (el, k) in enumerate(zip(elevations, counts)) for j in range(k)]
    else:
        raise UserError(f"unknown view layout {layout!r} (known: {', '.join(LAYOUTS)})")
    return np.stack(cams)


def case_cameras(spec: dict, vertices: np.ndarray, n_views: int, layout: str) -> tuple[np.ndarray, float]:
    """The case's ``n_views`` cameras of ``layout`` round its true mesh's ``vertices`` (view 0 its
    input view, at the case's azimuth and elevation) and their horizontal field of view."""
    lo, hi = vertices.min(0), vertices.max(0)
    cam, fov = spec.get("camera", {}), case_fov(spec)
    return view_cameras((lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2), n_views, cam.get("azimuth_deg", 0.0),
                        cam.get("elevation_deg", 22.0), layout, fov), fov


def mesh_case(path: str | Path, generator: str, up: str = "y", height: float | None = None) -> dict:
    """A case of no split for the mesh file at ``path`` (``ipm synth --mesh``; the recipe
    ``mesh_file``) as an object of ``generator``'s class, seen from the cases' default camera."""
    get_generator(generator)  # an unknown name is one clear error
    return {"name": Path(path).stem, "split": "none", "generator": generator,
            "description": f"the mesh file {Path(path).name}",
            "source": {"recipe": "mesh_file", "args": {"path": str(Path(path).resolve()), "up": up, "height": height}}}


def synthesize(case: str | dict, out: str | Path, n_views: int = 1, res: int = 256, spp: int = 64,
               progress: bool = True, layout: str = "hemi") -> None:
    """Render the case's references (a case name, or a case itself: :func:`mesh_case`) into ``out``
    (atomically: all or nothing)."""
    from tqdm import tqdm

    from ipm.io.semantic import save_labels
    from ipm.render.semantic import render_labels, render_tree_rgb
    from ipm.render.silhouette import SilhouetteRenderer
    from ipm.render.textured import render_painted

    if n_views < 1 or res < 16:
        raise UserError("need at least 1 view and 16 px")
    spec, case = (load_case(case), case) if isinstance(case, str) else (case, case["name"])
    if layout == "photo" and is_tree_case(spec):
        raise UserError(f"{case}: the photo layout renders cups and buildings, not trees")
    v, f, labels, uv = ground_truth_mesh(spec)
    c2w, fov = case_cameras(spec, v, n_views, layout)
    scheme, tree = semantic_scheme(spec), is_tree_case(spec)
    with atomic_dir(out) as tmp:
        if scheme:
            names, part_label = scheme
            top = max(names.values())
            semantic = render_labels(v, f, part_label[labels] - 1, c2w, fov, res, res, spp, n_parts=top)
        if tree:  # varied browns and greens that labels_from_rgb reads; masks = labelled pixels
            rgb = render_tree_rgb(v, f, labels, c2w, fov, res, res, spp, spec.get("texture_seed", 0))
            masks = (semantic > 0).astype(np.float32)
        elif layout == "photo":
            rgb, masks, lens = photographs(case, spec, v, f, labels, uv, c2w, fov, res, spp)
        else:
            rgb = render_painted(v, f, labels, uv, reference_appearance(spec, v, f, labels, uv), c2w, fov, res,
                                 res, spp)
            masks = SilhouetteRenderer(c2w, fov, res, res, spp=16).render(v, f)
        empty = [i for i in range(n_views) if not (masks[i] > 0.5).any()]
        if empty:
            raise UserError(f"{case}: the object covers no pixel of view(s) {', '.join(map(str, empty))} at {res} px "
                            f"(its true mesh spans {float(np.ptp(v, 0).max()):.3g} units)")
        frames = []
        for i in tqdm(range(n_views), desc=f"synth {case}", disable=not progress, leave=False):
            name = f"rgb/{i:03d}.jpg" if layout == "photo" else f"rgb/{i:03d}.png"
            save_rgb(tmp / name, rgb[i], PHOTO_QUALITY if layout == "photo" else None)
            save_mask(tmp / "masks" / f"{i:03d}.png", masks[i] > 0.5)
            frames.append({"file_path": name, "mask_path": f"masks/{i:03d}.png",
                           "transform_matrix": c2w[i]})
            if scheme:
                save_labels(tmp / "semantic" / f"{i:03d}.png", semantic[i], top)
                frames[-1]["semantic_path"] = f"semantic/{i:03d}.png"
        write_views(tmp / "transforms.json", fov, res, res, frames, scheme[0] if scheme else None,
                    lens if layout == "photo" else None, None if layout == "photo" else "reference")
        _write_reference(tmp, spec, v, f, labels)


def reference_appearance(case: dict, v, f, labels, uv) -> dict:
    """The textures a cup's or a building's reference views wear, one per part label
    (``ipm.render.appearance``; a building's parts by their material, a recipe's by its semantic
    class, a building's without classes (a mesh file's) walls), chosen by the case's ``texture_seed``; a
    mesh file's own base colours where it gives every part one."""
    from ipm.render.appearance import BUILDING_PARTS, reference_textures

    src = case["source"]
    if src.get("recipe") == "mesh_file":  # a model's own base colours, where its file gives them
        from datasets_synthetic.mesh_files import file_textures

        own = file_textures(src["args"]["path"], (v, f, labels, uv))
        if own is not None:
            return own
    seed, scheme = case.get("texture_seed", 0), semantic_scheme(case)
    if scheme is None and case.get("generator") == "buildings":
        return reference_textures("building", v, f, labels, uv, seed, {int(k): "wall" for k in np.unique(labels)})
    if scheme is None:
        return reference_textures("cup", v, f, labels, uv, seed)
    names, part_label = scheme
    by_label = {label: name for name, label in names.items()}
    parts = get_generator(src["generator"]).part_names if "generator" in src else ()
    materials = {int(k): BUILDING_PARTS[parts[k]] if k < len(parts) else by_label[int(part_label[k])]
                 for k in np.unique(labels)}
    return reference_textures("building", v, f, labels, uv, seed, materials)


def photographs(case: str, spec: dict, v, f, labels, uv, c2w: np.ndarray, fov: float, res: int, spp: int,
                backdrop: str | None = None):
    """A case's photographs from ``c2w`` with its :func:`photo_setting` (``backdrop`` in place of
    the setting's where given; the object in the materials of its reference views,
    :func:`reference_appearance`, or the setting's plain colour): linear RGB (n, res, res, 3), the
    true masks (n, res, res) and the lens (``ipm.io.lens.Lens``; None for a pinhole). Through a lens
    both are drawn by its pinhole twin on a canvas wide enough for all the lens sees, then
    distorted as the lens draws them."""
    from ipm.io.lens import nerfstudio_lens
    from ipm.render.photo_scene import render_photo
    from ipm.render.silhouette import SilhouetteRenderer

    shot = photo_setting(case)
    focal = 0.5 * res / np.tan(0.5 * fov)
    k1 = -shot["distortion"] / (2.0 * np.tan(0.5 * fov) ** 2)  # the corner's squared distance: 2 tan^2
    lens = nerfstudio_lens("OPENCV", focal, focal, 0.5 * res, 0.5 * res, {"k1": k1}, res, res)
    margin = lens.twin_margin() if lens is not None else 0
    size = res + 2 * margin
    canvas_fov = 2.0 * float(np.arctan(0.5 * size / focal))
    textures = reference_appearance(spec, v, f, labels, uv) if shot["plain"] is None else None
    rgb = render_photo(v, f, uv, c2w, canvas_fov, size, size, backdrop or shot["backdrop"], shot["seed"], textures,
                       shot["plain"], spp, labels)
    masks = SilhouetteRenderer(c2w, canvas_fov, size, size, spp=16).render(v, f)
    if lens is None:
        return rgb, masks, None
    return lens.from_twin(rgb, margin), lens.from_twin(masks, margin), lens


def _write_reference(folder: Path, spec: dict, v, f, labels) -> None:
    save_ply(folder / "reference.ply", v, f, labels)
    write_json(folder / "ground_truth.json", _recorded(spec))


def _recorded(spec: dict) -> dict:
    """The case as its ground_truth.json records it: a mesh file given by an absolute path by its
    name alone, so that no machine's folders reach an output."""
    src = spec.get("source", {})
    path = src.get("args", {}).get("path") if src.get("recipe") == "mesh_file" else None
    if path is None or not Path(path).is_absolute():
        return spec
    return {**spec, "source": {**src, "args": {**src["args"], "path": Path(path).name}}}


def write_reference(case: str, out: str | Path) -> None:
    """Only the ground truth: OUT/reference.ply (world frame, part labels) and OUT/ground_truth.json."""
    spec = load_case(case)
    v, f, labels, _ = ground_truth_mesh(spec)
    Path(out).mkdir(parents=True, exist_ok=True)
    _write_reference(Path(out), spec, v, f, labels)
