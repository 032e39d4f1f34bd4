"""Synthetic references: a case (generator + ground truth, or a foreign recipe) -> rendered views.

``ipm synth --case CASE --out DIR`` writes DIR/transforms.json, DIR/rgb/, DIR/masks/,
DIR/reference.ply and DIR/ground_truth.json. In the ``hemi`` layout view 0 is the single
input view (15-30 deg elevation) and further views lie on a Fibonacci hemisphere; the ``ring``
layout (COLMAP) puts textured views on rings. All views share the world frame.
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


def _closed_tubes(chains: list[tuple[np.ndarray, np.ndarray]], sides: int):
    """Closed tubes (rings along each polyline, fan caps at both ends, outward winding).

    ``chains``: (points (k, 3), radii (k,)) per tube, k >= 2. Ring frames are carried along each
    polyline by parallel transport, so tubes do not twist at bends.
    """
    verts, faces = [], []
    n_v = 0
    ang = 2 * np.pi * np.arange(sides) / sides
    k0, k1 = np.arange(sides), (np.arange(sides) + 1) % sides
    for pts, rad in chains:
        k = len(pts)
        seg = np.diff(pts, axis=0)
        seg /= np.linalg.norm(seg, axis=1, keepdims=True)
        tan = np.concatenate([seg[:1], seg[:-1] + seg[1:], seg[-1:]])
        tan /= np.linalg.norm(tan, axis=1, keepdims=True)
        ref = np.array([1.0, 0.0, 0.0]) if abs(tan[0, 0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        nrm = np.cross(tan[0], ref)
        nrm /= np.linalg.norm(nrm)
        rings = []
        for j in range(k):
            nrm = nrm - np.dot(nrm, tan[j]) * tan[j]  # parallel transport: keep the normal, drop its tangent part
            nrm /= np.linalg.norm(nrm)
            bin_ = np.cross(tan[j], nrm)
            rings.append(pts[j] + rad[j] * (np.cos(ang)[:, None] * nrm + np.sin(ang)[:, None] * bin_))
        ring_v = np.concatenate(rings)
        base = np.arange(k - 1)[:, None] * sides
        a, a1 = base + k0, base + k1
        b, b1 = a + sides, a1 + sides
        side = np.concatenate([np.stack([a, a1, b1], -1).reshape(-1, 3), np.stack([a, b1, b], -1).reshape(-1, 3)])
        c0, c1 = k * sides, k * sides + 1
        cap0 = np.stack([np.full(sides, c0), k1, k0], -1)
        cap1 = np.stack([np.full(sides, c1), (k - 1) * sides + k0, (k - 1) * sides + k1], -1)
        verts.append(np.concatenate([ring_v, pts[:1], pts[-1:]]))
        faces.append(np.concatenate([side, cap0, cap1]) + n_v)
        n_v += len(verts[-1])
    return np.concatenate(verts), np.concatenate(faces)


def _leaf_lenses(base: np.ndarray, along: np.ndarray, across: np.ndarray, normal: np.ndarray, thickness: float):
    """Closed diamond-shaped leaves: a rim of four points and an apex above and below the centre."""
    rim = np.stack([base, base + 0.5 * along + 0.5 * across, base + along, base + 0.5 * along - 0.5 * across], 1)
    centre = base + 0.5 * along
    up, down = centre + thickness * normal, centre - thickness * normal
    v = np.concatenate([rim, up[:, None], down[:, None]], 1).reshape(-1, 3)
    o = (np.arange(len(base)) * 6)[:, None]
    i, i1 = np.arange(4), (np.arange(4) + 1) % 4
    top = np.stack([np.broadcast_to(o + 4, (len(base), 4)), o + i1, o + i], -1)
    bottom = np.stack([np.broadcast_to(o + 5, (len(base), 4)), o + i, o + i1], -1)
    return v, np.concatenate([top, bottom], 1).reshape(-1, 3)


@RECIPES.register("space_colonisation_tree")
def space_colonisation_tree(trunk_height=0.45, crown_radius=0.5, crown_height=0.95, crown_flatten=0.3,
                            n_points=1500, influence=0.3, kill=0.07, step=0.035, up_tropism=0.15,
                            pipe_exponent=2.5, tip_radius=0.0035, twig_nodes=3, leaves_per_node=3,
                            leaf_length=0.075, leaf_width=0.045, sides=6, max_iterations=400, seed=0):
    """A tree grown by space colonisation (Runions, Lane and Prusinkiewicz 2007), numpy + scipy only.

    Attraction points fill a crown envelope (an ellipsoid of ``crown_radius`` and ``crown_height``
    above a bare trunk of ``trunk_height``, its lower part pressed flatter by ``crown_flatten``).
    From a root at the origin, each step every attraction point pulls its closest tree node
    within ``influence``; a pulled node grows a child ``step`` along the mean direction to its
    points (plus ``up_tropism`` towards the sky); points within ``kill`` of a node are removed.
    Branch radii follow the pipe model (``r_parent ** e = sum r_child ** e``) from ``tip_radius``.
    Branches are closed tubes (a chain follows its thickest child); closed diamond leaves
    (``leaves_per_node`` per node) sit on the last ``twig_nodes`` nodes of every twig.
    Returns world vertices (trunk base at the origin, standing on y = 0), faces, part labels
    (0 branch, 1 foliage) and UVs.
    """
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    centre_y = trunk_height + 0.5 * crown_height
    semi = np.array([crown_radius, 0.5 * crown_height, crown_radius])
    pts = np.empty((0, 3))
    while len(pts) < n_points:  # uniform in the envelope by rejection
        c = rng.uniform(-1.0, 1.0, (4 * n_points, 3))
        c = c[np.sum(c**2, 1) <= 1.0]
        c[:, 1] = np.where(c[:, 1] < 0, c[:, 1] * (1.0 - crown_flatten), c[:, 1])
        pts = np.concatenate([pts, c * semi + [0.0, centre_y, 0.0]])
    pts = pts[:n_points]
    nodes, parent = [np.zeros(3)], [-1]
    while nodes[-1][1] < trunk_height + 0.5 * influence:  # the bare trunk grows until the crown pulls it
        wobble = rng.normal(0.0, 0.08, 3) * [1.0, 0.0, 1.0]
        d = np.array([0.0, 1.0, 0.0]) + (wobble if len(nodes) > 2 else 0.0)
        nodes.append(nodes[-1] + step * d / np.linalg.norm(d))
        parent.append(len(nodes) - 2)
    up = np.array([0.0, 1.0, 0.0])
    for _ in range(max_iterations):
        if len(pts) == 0:
            break
        node_arr = np.array(nodes)
        dist, near = cKDTree(node_arr).query(pts, distance_upper_bound=influence)
        pulled = np.isfinite(dist)
        if not pulled.any():
            break
        pull = (pts[pulled] - node_arr[near[pulled]]) / dist[pulled, None]
        grow = np.zeros((len(nodes), 3))
        np.add.at(grow, near[pulled], pull)
        new = []
        for i in np.unique(near[pulled]):
            d = grow[i] / max(np.linalg.norm(grow[i]), 1e-9) + up_tropism * up
            norm = np.linalg.norm(d)
            if norm < 0.3:  # opposite pulls cancel: no growth here
                continue
            p = node_arr[i] + step * d / norm
            new.append(p)
            nodes.append(p)
            parent.append(int(i))
        if not new:
            break
        node_arr = np.array(nodes)
        d_kill, _ = cKDTree(node_arr).query(pts, distance_upper_bound=kill)
        pts = pts[~np.isfinite(d_kill)]
    nodes, parent = np.array(nodes), np.array(parent)
    n = len(nodes)
    children = [[] for _ in range(n)]
    for i in range(1, n):
        children[parent[i]].append(i)
    radius = np.full(n, tip_radius)
    for i in range(n - 1, 0, -1):  # children come after their parents
        if children[i]:
            radius[i] = np.sum(radius[children[i]] ** pipe_exponent) ** (1.0 / pipe_exponent)
    radius[0] = np.sum(radius[children[0]] ** pipe_exponent) ** (1.0 / pipe_exponent) * 1.15  # root flare
    # chains: each follows its thickest child; the other children start new chains at the fork
    chains, stack = [], [(0, [0])]
    while stack:
        i, chain = stack.pop()
        while children[i]:
            kids = sorted(children[i], key=lambda c: -radius[c])
            for c in kids[1:]:
                stack.append((c, [i, c]))
            i = kids[0]
            chain.append(i)
        if len(chain) >= 2:
            rad = radius[chain].copy()
            rad[0] = radius[chain[1]]  # a side branch starts with its own radius inside its parent
            chains.append((nodes[chain], rad))
    tv, tf = _closed_tubes(chains, sides)
    # leaves on the last twig_nodes nodes of every twig (a tip and its parents while they are thin)
    depth_to_tip = np.full(n, np.inf)
    for i in range(n - 1, -1, -1):
        depth_to_tip[i] = 0 if not children[i] else 1 + min(depth_to_tip[c] for c in children[i])
    holders = np.nonzero(depth_to_tip < twig_nodes)[0]
    holders = np.repeat(holders, leaves_per_node)
    m = len(holders)
    twig_dir = nodes[holders] - nodes[parent[holders]]
    twig_dir /= np.linalg.norm(twig_dir, axis=1, keepdims=True)
    along = twig_dir + rng.normal(0.0, 0.8, (m, 3))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    normal = up + rng.normal(0.0, 0.5, (m, 3))
    normal -= np.sum(normal * along, 1, keepdims=True) * along
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    across = np.cross(normal, along)
    size = rng.uniform(0.8, 1.2, (m, 1))
    lv, lf = _leaf_lenses(nodes[holders], along * leaf_length * size, across * leaf_width * size, normal,
                          0.05 * leaf_width)
    v = np.concatenate([tv, lv])
    f = np.concatenate([tf, lf + len(tv)])
    labels = np.concatenate([np.zeros(len(tf), int), np.ones(len(lf), int)])
    return v, f, labels, _cylindrical_uv(v)


space_colonisation_tree.semantic = True
"""Its parts are branch (0) and foliage (1): synth writes semantic label images (is_tree_case)."""


def is_tree_case(case: dict) -> bool:
    """True for cases reconstructed by the trees generator (or built by a tree recipe): their
    synth writes semantic label images (0 background, 1 branch, 2 foliage) beside the RGB."""
    src = case.get("source", {})
    recipe = RECIPES[src["recipe"]] if src.get("recipe") in RECIPES else None
    return "trees" in (case.get("generator"), src.get("generator")) or bool(getattr(recipe, "semantic", False))


def ground_truth_mesh(case: dict, lod: int = 2):
    """World-frame vertices, faces, part labels and UVs of a case's ground truth."""
    src = case["source"]
    if "generator" in src:
        gen = get_generator(src["generator"])
        if "preset" in src and src["preset"] not in gen.presets:
            raise UserError(f"unknown preset {src['preset']!r}")
        base = gen.presets[src["preset"]] if "preset" in src else None
        x = gen.spec.from_dict(src.get("params", {}), base)
        m = gen.mesh(x, lod)
        v, f, labels, uv = m.vertices, m.faces, m.labels, m.uv
    else:
        v, f, labels, uv = RECIPES[src["recipe"]](**src.get("args", {}))
    pose = case.get("pose", {})
    rot = trimesh.transformations.rotation_matrix(np.radians(pose.get("yaw_deg", 0.0)), [0, 1, 0])[:3, :3]
    v = pose.get("scale", 1.0) * np.asarray(v) @ rot.T + np.asarray(pose.get("translation", [0, 0, 0]))
    return v, np.asarray(f), np.asarray(labels), np.asarray(uv)


LAYOUTS = ("hemi", "ring")
"""View layouts: ``hemi`` (view 0 is the input view, the rest on a Fibonacci hemisphere; the
diffSDF views and ours) and ``ring`` (rings of at most 16 views, 22.5 degrees apart or closer,
so neighbouring images share enough texture for SIFT matching; the COLMAP views)."""


def view_cameras(center: np.ndarray, radius: float, n_views: int, azimuth: float, elevation: float,
                 layout: str = "hemi"):
    """Camera-to-world matrices of ``n_views`` views around the object in ``layout``."""
    dist = 1.3 * radius / np.sin(FOV_X / 2)
    if layout == "hemi":
        cams = [orbit_camera(center, dist, azimuth, elevation)]
        golden = np.pi * (3 - np.sqrt(5))
        for i in range(1, n_views):
            s = (i - 0.5) / max(n_views - 1, 1)
            cams.append(orbit_camera(center, dist, azimuth + np.degrees(golden * i), 5.0 + 70.0 * s))
    elif layout == "ring":
        n_rings = -(-n_views // 16)
        elevations = np.linspace(15.0, 60.0, n_rings) if n_rings > 1 else [30.0]
        counts = np.diff(np.linspace(0, n_views, n_rings + 1).round().astype(int))
        cams = [orbit_camera(center, dist, azimuth + 360.0 * (j + 0.5 * (r % 2)) / k, el)
                for r, (el, k) in enumerate(zip(elevations, counts)) for j in range(k)]
    else:
        raise UserError(f"unknown view layout {layout!r} (known: {', '.join(LAYOUTS)})")
    return np.stack(cams)


def synthesize(case: str, out: str | Path, n_views: int = 1, res: int = 256, spp: int = 64,
               progress: bool = True, layout: str = "hemi") -> None:
    """Render the case's references into ``out`` (atomically: all or nothing)."""
    from tqdm import tqdm

    from ipm.io.semantic import LABEL_NAMES, save_labels
    from ipm.render.semantic import render_labels, render_tree_rgb
    from ipm.render.silhouette import SilhouetteRenderer
    from ipm.render.textured import render_rgb

    if n_views < 1 or res < 16:
        raise UserError("need at least 1 view and 16 px")
    spec = load_case(case)
    v, f, labels, uv = ground_truth_mesh(spec)
    lo, hi = v.min(0), v.max(0)
    center, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
    cam = spec.get("camera", {})
    c2w = view_cameras(center, radius, n_views, cam.get("azimuth_deg", 0.0), cam.get("elevation_deg", 22.0), layout)
    tree = is_tree_case(spec)
    with atomic_dir(out) as tmp:
        if tree:  # part colours (brown, green) that labels_from_rgb reads; masks = labelled pixels
            semantic = render_labels(v, f, labels, c2w, FOV_X, res, res, spp)
            rgb = render_tree_rgb(v, f, labels, c2w, FOV_X, res, res, spp)
            masks = (semantic > 0).astype(np.float32)
        else:
            rgb = render_rgb(v, f, uv, c2w, FOV_X, res, res, spec.get("texture_seed", 0), spp)
            masks = SilhouetteRenderer(c2w, FOV_X, res, res, spp=16).render(v, f)
        frames = []
        for i in tqdm(range(n_views), desc=f"synth {case}", disable=not progress, leave=False):
            save_rgb(tmp / "rgb" / f"{i:03d}.png", rgb[i])
            save_mask(tmp / "masks" / f"{i:03d}.png", masks[i] > 0.5)
            frames.append({"file_path": f"rgb/{i:03d}.png", "mask_path": f"masks/{i:03d}.png",
                           "transform_matrix": c2w[i]})
            if tree:
                save_labels(tmp / "semantic" / f"{i:03d}.png", semantic[i])
                frames[-1]["semantic_path"] = f"semantic/{i:03d}.png"
        write_views(tmp / "transforms.json", FOV_X, res, res, frames, LABEL_NAMES if tree else None)
        _write_reference(tmp, spec, v, f, labels)


def _write_reference(folder: Path, spec: dict, v, f, labels) -> None:
    save_ply(folder / "reference.ply", v, f, labels)
    write_json(folder / "ground_truth.json", spec)


def write_reference(case: str, out: str | Path) -> None:
    """Only the ground truth: OUT/reference.ply (world frame, part labels) and OUT/ground_truth.json."""
    spec = load_case(case)
    v, f, labels, _ = ground_truth_mesh(spec)
    Path(out).mkdir(parents=True, exist_ok=True)
    _write_reference(Path(out), spec, v, f, labels)
