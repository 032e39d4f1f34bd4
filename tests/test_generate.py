"""``ipm generate``: parameters back to meshes at every level of detail, GLB parts, materials,
normals and parameters; clear errors for bad parameter files."""
from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ipm.generate import generate
from ipm.generators import get_generator
from tests.conftest import slow_except
from tests.test_cli import _one_line_error, ipm

VALIDATOR = Path(__file__).parent / "gltf"
"""The Khronos glTF validator (npm package gltf-validator, installed by scripts/setup.sh)."""


def _glb_json(path) -> dict:
    """The JSON chunk of a GLB file."""
    data = path.read_bytes()
    assert data[:4] == b"glTF"
    (length,) = struct.unpack("<I", data[12:16])
    return json.loads(data[20:20 + length])


def _params_file(tmp_path, generator: str, x: np.ndarray, pose: dict | None = None):
    gen = get_generator(generator)
    path = tmp_path / f"{generator}_params.json"
    path.write_text(json.dumps({"generator": generator, "params": gen.spec.as_dict(x),
                                **({"pose": pose} if pose else {})}))
    return path


@pytest.mark.parametrize("generator,preset", slow_except([("buildings", "villa"), ("dishes", "mug")], "dishes"))
def test_every_level_of_detail_round_trips(tmp_path, generator, preset):
    gen = get_generator(generator)
    x = gen.presets[preset]
    params = _params_file(tmp_path, generator, x)
    for lod in gen.lods:
        out = tmp_path / f"lod{lod}.glb"
        info = generate(generator, params, lod, out)
        mesh = gen.mesh(x, lod)
        tree = _glb_json(out)
        names = [gen.part_names[k] for k in np.unique(mesh.labels)]
        assert [n["name"] for n in tree["nodes"] if "mesh" in n] == names
        assert [m["name"] for m in tree["materials"]] == names  # one material per part
        assert all("NORMAL" in p["attributes"] for m in tree["meshes"] for p in m["primitives"])
        extras = tree["scenes"][0]["extras"]
        assert extras["generator"] == generator and extras["lod"] == lod
        np.testing.assert_allclose(gen.spec.from_dict(extras["params"]), x)
        scene = trimesh.load(out)
        assert sum(len(g.faces) for g in scene.geometry.values()) == len(mesh.faces) == info["triangles"]


def test_world_applies_the_reconstructions_pose(tmp_path):
    gen = get_generator("dishes")
    x = gen.presets["mug"]
    pose = {"yaw": np.pi / 2, "tilt_x": 0.0, "tilt_z": 0.0, "translation": [0.1, 0.0, -0.2], "scale": 2.0}
    params = _params_file(tmp_path, "dishes", x, pose)
    generate("dishes", params, 1, tmp_path / "world.ply", world=True)
    world = trimesh.load(tmp_path / "world.ply", process=False)
    v = gen.mesh(x, 1).vertices
    expected = 2.0 * np.stack([v[:, 2], v[:, 1], -v[:, 0]], 1) + [0.1, 0.0, -0.2]  # R_y(90 deg)
    np.testing.assert_allclose(world.vertices, expected, atol=1e-5)
    generate("dishes", params, 1, tmp_path / "object.ply")  # default: upright at the origin
    np.testing.assert_allclose(trimesh.load(tmp_path / "object.ply", process=False).vertices, v, atol=1e-6)


@pytest.mark.parametrize("content,message", [
    ({"params": {"width": 1.0}}, "holds parameters of 'buildings'"),  # read as dishes below
    ({"generator": "dishes", "params": {"teapot_spout": 1.0}}, "unknown parameter 'teapot_spout'"),
    ({"generator": "dishes", "params": {"y_scale": "tall"}}, "must be a number"),
    ({"generator": "dishes", "params": {"y_scale": 9.0}}, "outside the generator's bounds: y_scale"),
    ("{not json", "malformed parameter file"),
])
def test_bad_parameter_files_give_one_line(tmp_path, content, message):
    path = tmp_path / "params.json"
    if isinstance(content, dict) and "generator" not in content:
        content = {"generator": "buildings", **content}
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    out = tmp_path / "mesh.glb"
    res = ipm("generate", "--generator", "dishes", "--params", str(path), "--out", str(out))
    assert message in _one_line_error(res)
    assert not out.exists()


@pytest.mark.slow
def test_bad_options_give_one_line(tmp_path):
    params = _params_file(tmp_path, "dishes", get_generator("dishes").presets["mug"])
    out = tmp_path / "mesh.glb"
    for args, message in ((["--lod", "7"], "levels of detail 0, 1, 2, not 7"),
                          (["--world"], "has no pose"),
                          (["--out", str(tmp_path / "mesh.obj")], "must end in .glb, .ply or .json")):
        res = ipm("generate", "--generator", "dishes", "--params", str(params), "--out", str(out), *args)
        assert message in _one_line_error(res)
    assert not out.exists()
    res = ipm("generate", "--generator", "dishes", "--params", str(tmp_path / "none.json"), "--out", str(out))
    assert "parameter file not found" in _one_line_error(res)


@pytest.mark.slow
def test_glbs_pass_the_khronos_validator(tmp_path):
    """Every level of detail of a building and a cup, plain and textured (one baseColorTexture per
    part, TEXCOORD_0), a textured tree, and a reconstruction's GLB layout (posed): no errors and no
    warnings from the Khronos glTF validator."""
    from ipm.io.views import save_texture

    assert (VALIDATOR / "node_modules" / "gltf-validator").is_dir(), "run scripts/setup.sh (npm ci in tests/gltf)"
    files = []
    rng = np.random.default_rng(0)
    for generator, preset in (("buildings", "townhouse"), ("dishes", "mug")):
        gen = get_generator(generator)
        pose = {"yaw": 0.3, "tilt_x": 0.0, "tilt_z": 0.0, "translation": [0.0, 0.0, 0.1], "scale": 1.2}
        params = _params_file(tmp_path, generator, gen.presets[preset], pose)
        textures = tmp_path / f"{generator}_textures"
        for name in gen.part_names:
            save_texture(textures / f"{name}.png", rng.integers(0, 256, (16, 16, 3)))
        for lod in gen.lods:
            files.append(tmp_path / f"{generator}_{lod}.glb")
            generate(generator, params, lod, files[-1], world=lod == max(gen.lods))
            files.append(tmp_path / f"{generator}_{lod}_textured.glb")
            generate(generator, params, lod, files[-1], textures=textures)
            assert "textures" in _glb_json(files[-1])
    tree = get_generator("trees")  # a painted tree at its lowest level (the GA's results wear textures too)
    textures = tmp_path / "trees_textures"
    for name in tree.part_names:
        save_texture(textures / f"{name}.png", rng.integers(0, 256, (16, 16, 3)))
    files.append(tmp_path / "trees_0_textured.glb")
    generate("trees", _params_file(tmp_path, "trees", tree.presets["bush"], pose), 0, files[-1], textures=textures)
    res = subprocess.run(["node", str(VALIDATOR / "validate.js"), *map(str, files)], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    reports = [json.loads(line) for line in res.stdout.splitlines()]
    assert len(reports) == len(files)
    for r in reports:
        assert r["errors"] == 0 and r["warnings"] == 0, r
