"""A benchmark case from a mesh file made by any tool (the recipe ``mesh_file``)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from ipm.errors import UserError


def _truth(path, up="y"):
    """The ground truth (vertices, faces, labels, corner UVs) of a mesh-file case of ``path``."""
    from ipm.synth import ground_truth_mesh

    return ground_truth_mesh({"name": "file", "source": {"recipe": "mesh_file", "args": {"path": str(path), "up": up}}})


def _z_up_mug(path):
    """A closed z-up mug-like solid (a body and a handle, wound inwards on purpose) written to ``path``."""
    body = trimesh.creation.cylinder(0.4, 1.2, sections=32)  # along z, from z = -0.6 to 0.6
    handle = trimesh.creation.box((0.15, 0.1, 0.5), trimesh.transformations.translation_matrix([0.5, 0, 0.1]))
    handle.invert()
    scene = trimesh.Scene()
    scene.add_geometry(body, geom_name="body")
    scene.add_geometry(handle, geom_name="handle")
    scene.export(path)
    return path


def test_a_mesh_file_stands_upright_on_the_ground_at_its_height(tmp_path):
    """A z-up GLB of two geometries: y up, on y = 0, centred on the y axis, scaled to the height
    asked for; one label per geometry; every part wound outwards (positive volume); UVs a corner."""
    from datasets_synthetic.mesh_files import mesh_file

    v, f, labels, uv = mesh_file(str(_z_up_mug(tmp_path / "mug.glb")), up="z", height=0.9)
    assert v[:, 1].min() == pytest.approx(0.0, abs=1e-9) and np.ptp(v[:, 1]) == pytest.approx(0.9)
    lo, hi = v.min(0), v.max(0)
    assert (lo[0] + hi[0]) / 2 == pytest.approx(0.0, abs=1e-9) and (lo[2] + hi[2]) / 2 == pytest.approx(0.0, abs=1e-9)
    assert np.ptp(v[:, 0]) > np.ptp(v[:, 2])  # the handle sticks out along x, as in the file
    assert sorted(np.unique(labels)) == [0, 1] and len(labels) == len(f) and uv.shape == (len(f), 3, 2)
    for k in (0, 1):
        part = trimesh.Trimesh(v, f[labels == k], process=True)
        assert part.is_watertight and part.volume > 0
    same = mesh_file(str(tmp_path / "mug.glb"), up="z")  # the file's own units
    assert np.ptp(same[0][:, 1]) == pytest.approx(1.2)


def test_a_mesh_file_case_wears_its_class_materials(tmp_path):
    """A case of the buildings class from a mesh file: the world frame by its pose; the reference
    views' materials a building's (no part classes: walls) where a cup's would be a glaze; a tree
    from a mesh file is refused (the GA reads branch and foliage from the references' colours)."""
    from ipm.synth import ground_truth_mesh, reference_appearance, semantic_scheme

    path = str(_z_up_mug(tmp_path / "block.glb"))
    case = {"name": "building_file", "generator": "buildings", "pose": {"yaw_deg": 90.0, "scale": 2.0},
            "source": {"recipe": "mesh_file", "args": {"path": path, "up": "z", "height": 0.5}}}
    v, f, labels, uv = ground_truth_mesh(case)
    assert np.ptp(v[:, 1]) == pytest.approx(1.0) and np.ptp(v[:, 2]) > np.ptp(v[:, 0])  # scaled, turned
    assert semantic_scheme(case) is None  # no semantic images: no window term from them
    walls = reference_appearance(case, v, f, labels, uv)
    cup = reference_appearance({**case, "generator": "dishes"}, v, f, labels, uv)
    assert set(walls) == set(cup) == {0, 1} and not np.allclose(walls[0], cup[0])
    with pytest.raises(UserError, match="tree"):
        ground_truth_mesh({**case, "generator": "trees"})


@pytest.mark.parametrize("args, message", [
    ({"path": "no/such.glb"}, "mesh file not found"),
    ({"path": "NOTMESH"}, "unreadable mesh file|holds no triangles"),
    ({"path": "MUG", "up": "x"}, "up must be one of y, z"),
    ({"path": "MUG", "height": -1.0}, "height must be a positive number"),
    ({"path": "MUG", "height": float("nan")}, "height must be a positive number"),
    ({"path": "MUG", "height": "0.9"}, "height must be a positive number"),
])
def test_a_bad_mesh_file_is_one_clear_error(tmp_path, args, message):
    from datasets_synthetic.mesh_files import mesh_file

    (tmp_path / "not_a_mesh.obj").write_text("this is not a mesh\n")
    mug = str(_z_up_mug(tmp_path / "mug.glb"))
    args = {**args, "path": {"NOTMESH": str(tmp_path / "not_a_mesh.obj"), "MUG": mug}.get(args["path"], args["path"])}
    with pytest.raises(UserError, match=message):
        mesh_file(**args)


def test_a_mesh_file_case_is_synthesized_like_the_recipes(tmp_path, monkeypatch, mitsuba_cpu):
    """synth renders a cup case from a mesh file: its true mesh written, the input view's mask
    where the mesh is, colours and the transforms a fit reads."""
    import ipm.synth as synth
    from ipm.io.views import load_views

    case = {"name": "cup_file", "split": "dev", "generator": "dishes", "camera": {"elevation_deg": 20.0},
            "source": {"recipe": "mesh_file", "args": {"path": str(_z_up_mug(tmp_path / "mug.glb")), "up": "z",
                                                       "height": 0.8}}}
    monkeypatch.setattr(synth, "load_case", lambda name: case)
    synth.synthesize("cup_file", tmp_path / "views", n_views=2, res=48, spp=4, progress=False)
    views = load_views(tmp_path / "views" / "transforms.json")
    assert (tmp_path / "views" / "reference.ply").is_file() and len(views.masks) == 2
    assert all(0.02 < m.mean() < 0.8 for m in views.masks)
    assert trimesh.load(tmp_path / "views" / "reference.ply").bounds[1, 1] == pytest.approx(0.8, abs=1e-6)
    recorded = (tmp_path / "views" / "ground_truth.json").read_text()
    assert str(tmp_path) not in recorded and json.loads(recorded)["source"]["args"]["path"] == "mug.glb"


def test_a_mesh_file_in_millimetres_renders_as_in_metres(tmp_path, monkeypatch, mitsuba_cpu):
    """Without a height a file keeps its units, and the cameras frame it by its size: the same mug
    written in millimetres (1 200 units tall) gives the masks it gives in metres, where a sensor's
    fixed far plane (10 000 units) left every view empty. A view the object does not reach is one
    clear error and no output."""
    import ipm.render.silhouette as silhouette
    import ipm.synth as synth
    from ipm.io.views import load_views
    from ipm.render.cameras import CLIP, clip_planes, look_at

    masks = []
    for name, scale in (("metres", 1.0), ("millimetres", 1000.0)):
        mug = trimesh.load(_z_up_mug(tmp_path / "mug.glb"))
        mug.apply_scale(scale)
        mug.export(tmp_path / f"{name}.glb")
        synth.synthesize(synth.mesh_case(tmp_path / f"{name}.glb", "dishes", up="z"), tmp_path / name, n_views=2,
                         res=32, spp=2, progress=False)
        masks.append(load_views(tmp_path / name / "transforms.json").masks)
    assert masks[0].any(axis=(1, 2)).all() and np.array_equal(masks[0], masks[1])
    assert clip_planes(look_at([0, 1, 3], [0, 0, 0])) == CLIP  # the scenes' own scale: as before
    assert clip_planes(look_at([0, 1e4, 3e4], [0, 0, 0]))[1] > 3.2e4
    monkeypatch.setattr(silhouette.SilhouetteRenderer, "render", lambda self, v, f: np.zeros((2, 32, 32)))
    with pytest.raises(UserError, match="covers no pixel of view"):
        synth.synthesize(synth.mesh_case(tmp_path / "metres.glb", "dishes", up="z"), tmp_path / "none", n_views=2,
                         res=32, spp=2, progress=False)
    assert not (tmp_path / "none").exists()


@pytest.mark.slow
def test_ipm_synth_renders_a_mesh_file_without_a_case_file(tmp_path):
    """``ipm synth --mesh FILE --generator G``: the references of a model as a case of that class;
    one of --case and --mesh, --mesh with its generator, else one clear error and no output."""
    import subprocess
    import sys

    def ipm(*argv):
        return subprocess.run([sys.executable, "-m", "ipm.cli", "synth", *argv, "--res", "32", "--spp", "4",
                               "--threads", "1", "--quiet"], capture_output=True, text=True)

    mug = str(_z_up_mug(tmp_path / "mug.glb"))
    out = tmp_path / "views"
    done = ipm("--mesh", mug, "--generator", "dishes", "--up", "z", "--height", "0.8", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert trimesh.load(out / "reference.ply").bounds[1, 1] == pytest.approx(0.8, abs=1e-6)
    assert (out / "masks").is_dir() and (out / "transforms.json").is_file()
    for argv, message in ((["--mesh", mug], "--mesh needs --generator"), ([], "give one of --case and --mesh"),
                          (["--case", "cup_1", "--generator", "dishes"], "--generator applies to --mesh only"),
                          (["--mesh", mug, "--generator", "teapots"], "unknown generator")):
        bad = ipm(*argv, "--out", str(tmp_path / "bad"))
        assert bad.returncode == 2 and message in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
        assert not (tmp_path / "bad").exists()


def test_a_textured_model_wears_its_own_base_colour(tmp_path, monkeypatch, mitsuba_cpu):
    """A z-up GLB whose texture is red above and blue below (glTF's rows): the references wear it,
    the object's upper pixels red and its lower ones blue; a file without textures wears its
    class's materials."""
    from PIL import Image

    import ipm.synth as synth
    from datasets_synthetic.mesh_files import file_textures
    from ipm.io.views import load_views

    m = trimesh.creation.cylinder(0.3, 1.0, sections=32)  # along z
    uv = np.stack([(np.arctan2(m.vertices[:, 1], m.vertices[:, 0]) / (2 * np.pi)) % 1, m.vertices[:, 2] + 0.5], 1)
    image = np.zeros((64, 64, 3), np.uint8)
    image[:32], image[32:] = (220, 30, 30), (30, 30, 220)  # the first rows at v = 1: the top
    m.visual = trimesh.visual.TextureVisuals(uv=uv, material=trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.fromarray(image)))
    m.export(tmp_path / "can.glb")
    case = {"name": "cup_can", "split": "dev", "generator": "dishes", "camera": {"elevation_deg": 10.0},
            "source": {"recipe": "mesh_file", "args": {"path": str(tmp_path / "can.glb"), "up": "z", "height": 1.0}}}
    own = file_textures(case["source"]["args"]["path"], synth.ground_truth_mesh(case), size=32)
    assert own[0].shape == (32, 32, 3) and own[0][2, 16, 0] > 0.5 > own[0][2, 16, 2] and own[0][29, 16, 2] > 0.5
    mug = str(_z_up_mug(tmp_path / "mug.glb"))
    assert file_textures(mug, _truth(mug)) is None  # no base colour: class materials
    monkeypatch.setattr(synth, "load_case", lambda name: case)
    synth.synthesize("cup_can", tmp_path / "views", n_views=1, res=48, spp=4, progress=False)
    views = load_views(tmp_path / "views" / "transforms.json")
    rgb = np.asarray(Image.open(tmp_path / "views" / "rgb" / sorted(p.name for p in (tmp_path / "views" / "rgb").iterdir())[0]),
                     np.float64)[..., :3]
    rows = np.nonzero(views.masks[0].any(1))[0]
    top, bottom = rows[: len(rows) // 3], rows[-len(rows) // 3:]
    upper = rgb[top][views.masks[0][top] > 0.5].mean(0)
    lower = rgb[bottom][views.masks[0][bottom] > 0.5].mean(0)
    assert upper[0] > upper[2] + 30 and lower[2] > lower[0] + 30


def test_a_scan_wears_its_vertex_colours(tmp_path):
    """A z-up PLY whose vertices are red above and blue below (a scan's colours, no UVs): its
    colours baked onto the case's UVs, red in the bitmap's top rows (glTF's rows) and blue in its
    bottom ones; a PLY's bytes read as sRGB, a glTF's as linear; a part of a scene without colours
    leaves the file to its class's materials."""
    from datasets_synthetic.mesh_files import file_textures, mesh_file

    m = trimesh.creation.cylinder(0.3, 1.0, sections=32)  # along z
    m = m.subdivide().subdivide()
    colours = np.where(m.vertices[:, 2:3] > 0, [[220, 30, 30, 255]], [[30, 30, 220, 255]]).astype(np.uint8)
    m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=colours)
    m.export(tmp_path / "scan.ply")
    own = file_textures(str(tmp_path / "scan.ply"), _truth(tmp_path / "scan.ply", up="z"), size=32)
    assert set(own) == {0} and own[0].shape == (32, 32, 3) and np.isfinite(own[0]).all()
    assert own[0][3, 16, 0] > 0.5 > own[0][3, 16, 2] and own[0][28, 16, 2] > 0.5 > own[0][28, 16, 0]
    assert len(mesh_file(str(tmp_path / "scan.ply"), up="z")[0]) == len(m.vertices)
    halves = m.copy()  # red where x > 0 (about the UVs' seam, u near 0 and 1), blue elsewhere
    halves.visual = trimesh.visual.ColorVisuals(halves, vertex_colors=np.where(
        m.vertices[:, :1] > 0, [[220, 30, 30, 255]], [[30, 30, 220, 255]]).astype(np.uint8))
    halves.export(tmp_path / "halves.ply")
    middle = file_textures(str(tmp_path / "halves.ply"), _truth(tmp_path / "halves.ply", up="z"), size=32)[0][4:28, 16]
    assert (middle[:, 2] > 0.5).all() and (middle[:, 0] < 0.1).all()  # blue opposite the seam, red nowhere there
    grey = trimesh.creation.box((0.2, 0.2, 0.2))  # one colour: sRGB bytes in a PLY, linear in a glTF
    grey.visual = trimesh.visual.ColorVisuals(grey, vertex_colors=np.tile([128, 128, 128, 255], (8, 1)).astype(np.uint8))
    for suffix, want in ((".ply", 0.2158), (".glb", 128 / 255)):
        grey.export(tmp_path / f"grey{suffix}")
        grey_file = tmp_path / f"grey{suffix}"
        assert file_textures(str(grey_file), _truth(grey_file), size=8)[0] == pytest.approx(want, abs=1e-3)
    bare = trimesh.creation.box((0.2, 0.2, 0.2))
    trimesh.Scene([m, bare]).export(tmp_path / "two.glb")
    assert file_textures(str(tmp_path / "two.glb"), _truth(tmp_path / "two.glb", up="z"), size=32) is None


def _glb(path, vertices, faces, factor, uv=None, colours=None):
    """A one-primitive GLB written byte by byte: POSITION, TEXCOORD_0 where ``uv`` is given,
    COLOR_0 (unsigned bytes, normalized) where ``colours`` (V, 4) is, a material of base colour
    ``factor`` (linear RGBA)."""
    import struct

    arrays = [(np.asarray(vertices, np.float32), "VEC3", 5126, False), (np.asarray(faces, np.uint32).ravel(), "SCALAR", 5125, False)]
    if uv is not None:
        arrays.append((np.asarray(uv, np.float32), "VEC2", 5126, False))
    if colours is not None:
        arrays.append((np.asarray(colours, np.uint8), "VEC4", 5121, True))
    blob, views, accessors = b"", [], []
    for k, (a, kind, component, normalized) in enumerate(arrays):
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": a.nbytes})
        accessor = {"bufferView": k, "componentType": component, "count": len(a), "type": kind}
        if k == 0:
            accessor |= {"min": a.min(0).tolist(), "max": a.max(0).tolist()}
        accessors.append(accessor | ({"normalized": True} if normalized else {}))
        blob += a.tobytes() + b"\0" * (-a.nbytes % 4)
    attributes = {"POSITION": 0} | ({"TEXCOORD_0": 2} if uv is not None else {})
    if colours is not None:
        attributes["COLOR_0"] = len(arrays) - 1
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": attributes, "indices": 1, "material": 0}]}],
           "materials": [{"pbrMetallicRoughness": {"baseColorFactor": list(factor)}}],
           "buffers": [{"byteLength": len(blob)}], "bufferViews": views, "accessors": accessors}
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
    return path


def test_a_models_own_uvs_colours_and_factors_as_gltf_has_them(tmp_path):
    """A file's UVs are its own per corner (a triangle spanning the whole texture is not taken for
    one across a revolved part's seam); a factor without UVs is the part's colour; COLOR_0 beside a
    factor multiplies it (glTF's product); a part without UVs beside one with them keeps the
    other's UVs and is given the angle and height."""
    from datasets_synthetic.mesh_files import file_textures, mesh_file

    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    box = trimesh.Trimesh(square, trimesh.creation.box().faces, process=False)
    box.fix_normals()
    whole = np.where(square[:, :2] > 0.5, 1.0, 0.0)  # each corner at a corner of the texture
    _glb(tmp_path / "atlas.glb", box.vertices, box.faces, (0.5, 0.5, 0.5, 1.0), uv=whole)
    v, f, labels, corner = mesh_file(str(tmp_path / "atlas.glb"))
    file_uv = whole.copy()
    file_uv[:, 1] = 1.0 - file_uv[:, 1]  # trimesh's origin at the bottom
    assert np.array_equal(corner, file_uv[f]) and corner[..., 0].max() == 1.0
    assert np.ptp(corner[..., 0], axis=1).max() == 1.0  # a triangle across the texture, kept so

    _glb(tmp_path / "plain.glb", box.vertices, box.faces, (0.2, 0.4, 0.8, 1.0))  # a factor, no UVs
    assert file_textures(str(tmp_path / "plain.glb"), _truth(tmp_path / "plain.glb"), size=8)[0] == pytest.approx(
        np.broadcast_to([0.2, 0.4, 0.8], (8, 8, 3)), abs=2e-3)
    grey = np.tile([255, 128, 0, 255], (8, 1))
    _glb(tmp_path / "tinted.glb", box.vertices, box.faces, (0.5, 1.0, 1.0, 1.0), uv=whole, colours=grey)
    tinted = file_textures(str(tmp_path / "tinted.glb"), _truth(tmp_path / "tinted.glb"), size=8)[0]
    assert tinted[2:6, 2:6] == pytest.approx(np.broadcast_to([0.5, 128 / 255, 0.0], (4, 4, 3)), abs=2e-3)

    bare = trimesh.creation.cylinder(0.3, 1.0, sections=16)
    bare.apply_translation([3.0, 0.0, 0.0])
    trimesh.Scene([trimesh.load(tmp_path / "atlas.glb", force="mesh", process=False), bare]).export(tmp_path / "two.glb")
    v, f, labels, corner = mesh_file(str(tmp_path / "two.glb"))
    k = int(np.bincount(labels).argmin())  # the box: 12 triangles
    own = f[labels == k]
    assert np.array_equal(corner[labels == k], file_uv[own - own.min()])  # its own UVs
    u = corner[labels != k][..., 0]
    assert (np.ptp(u, axis=1) < 0.5).all() and u.max() > 0.9  # the cylinder's angle, unwrapped at its seam
