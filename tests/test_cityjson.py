"""CityJSON 2.0 out: a building's city model is schema-valid, read by cjio, one closed solid per
wing with ground, wall and roof surfaces whose volumes add up to the union of its solids; written
beside every buildings result and by ``ipm generate --format cityjson``."""
from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ipm.generators import get_generator
from ipm.io.cityjson import METRES_PER_UNIT, schema_errors, solid_volume

GEN = get_generator("buildings")
CASES = {**GEN.presets, **{f"sample_{s}": GEN.sample(np.random.default_rng(s)) for s in range(3)},
         "u_and_annex": GEN.spec.from_dict({"template": 3, "annex": 1, "roof_type": 1, "wing1_roof": 2, "wing2_roof": 7,
                                            "wing3_roof": 0, "wing1_floors": 2, "wing2_floors": 1, "wing3_floors": 1,
                                            "wing3_shift": 0.1}, GEN.presets["house"])}


@pytest.fixture(scope="module")
def models():
    return {name: GEN.city_model(x) for name, x in CASES.items()}


def _points(doc):
    t = doc["transform"]
    return np.asarray(doc["vertices"], np.float64) * t["scale"] + t["translate"]


def _parts(doc) -> list[str]:
    return [k for k, o in doc["CityObjects"].items() if o["type"] == "BuildingPart"]


def _surfaces(doc, part: str = "building-part-0"):
    geometry = doc["CityObjects"][part]["geometry"][0]
    kinds = [s["type"] for s in geometry["semantics"]["surfaces"]]
    return list(zip(geometry["boundaries"][0], (kinds[i] for i in geometry["semantics"]["values"][0])))


def _closed(doc, part: str) -> bool:
    """Every edge of every ring walked once each way: the rings share the shell's edges."""
    edges = Counter((a, b) for surface, _ in _surfaces(doc, part) for ring in surface
                    for a, b in zip(ring, ring[1:] + ring[:1]))
    return all(count == 1 and edges[(b, a)] == 1 for (a, b), count in edges.items())


@pytest.mark.parametrize("name", sorted(CASES))
def test_the_city_model_is_valid_cityjson_and_one_closed_solid_per_wing(models, name):
    doc = models[name]
    assert schema_errors(doc) == []
    assert all(isinstance(c, int) for v in doc["vertices"] for c in v)
    wings = GEN._structure(GEN.topology_key(CASES[name]))["wings"]
    assert Counter(o["type"] for o in doc["CityObjects"].values()) == {"Building": 1, "BuildingPart": 1 + len(wings)}
    assert doc["CityObjects"]["building"]["children"] == _parts(doc)
    pts = _points(doc)
    for part in _parts(doc):
        assert _closed(doc, part)
        assert solid_volume(doc, part) > 0  # outward: counter-clockwise outer rings seen from outside
        kinds = {kind for _, kind in _surfaces(doc, part)}
        assert {"GroundSurface", "WallSurface", "RoofSurface"} <= kinds
        for surface, kind in _surfaces(doc, part):
            ring = pts[surface[0]]
            normal = np.cross(ring - ring.mean(0), np.roll(ring, -1, 0) - ring.mean(0)).sum(0)
            normal /= np.linalg.norm(normal)
            assert np.abs((ring - ring[0]) @ normal).max() < 2e-3  # planar to the millimetre's rounding
            if kind == "GroundSurface":
                assert normal[2] < -0.99 and np.allclose(ring[:, 2], 0.0)
            if kind == "RoofSurface":
                assert normal[2] > 0.05
            if kind == "WallSurface":
                assert abs(normal[2]) <= 0.05


def test_the_wings_parts_do_not_overlap_and_fill_the_building(models):
    """The parts' volumes add up to the union of every solid (each wing less the main wing), and
    each wing carries its own roof shape and storeys."""
    from ipm.io.cityjson import union_shell

    x, doc = CASES["u_and_annex"], models["u_and_annex"]
    mesh = GEN.mesh(x, 1)
    keep = np.isin(mesh.labels, [0, 2, 3])  # walls, frames, roof: the shell
    v, tri, _ = union_shell(mesh.vertices, mesh.faces[keep], np.full(keep.sum(), "wall", object))
    union = trimesh.Trimesh(v, tri).volume * METRES_PER_UNIT ** 3
    assert sum(solid_volume(doc, part) for part in _parts(doc)) == pytest.approx(union, rel=1e-4)
    shapes = [doc["CityObjects"][part]["attributes"]["roof:shape"] for part in _parts(doc)]
    assert shapes == ["gabled", "hipped", "gambrel", "flat"]
    assert [doc["CityObjects"][part]["attributes"]["building:levels"] for part in _parts(doc)] == [2, 2, 1, 1]


@pytest.mark.parametrize("name", ["house", "tower", "u_and_annex"])
def test_cjio_reads_the_written_files(models, name, tmp_path):
    """cjio (its command line, in a process of its own: importing cjio replaces the json module's
    float encoder for the whole process) reads the file as CityJSON 2.0 with the building and its part."""
    from ipm.io.cityjson import write_city_json

    path = tmp_path / "building.city.json"
    write_city_json(path, models[name])
    res = subprocess.run([str(Path(sys.executable).with_name("cjio")), str(path), "info"], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    parts = len(_parts(models[name]))
    assert "CityJSON version = 2.0" in res.stdout and "Building (1)" in res.stdout and f"BuildingPart ({parts})" in res.stdout


def test_a_flat_roofed_block_has_the_volume_of_its_solids(models):
    """The townhouse (flat roof, no chimney) at level 1: walls, the cornice round their top and the
    roof slab over the overhang; the union's volume from the polygons alone."""
    x = GEN.spec.as_dict(CASES["townhouse"])
    w, d, co, ch, o, rt = (x[k] for k in ("width", "depth", "cornice_offset", "cornice_height", "roof_overhang",
                                           "roof_thickness"))
    top = x["floors"] * x["floor_height"] + x["ground_extra"]
    volume = w * d * top + ((w + 2 * co) * (d + 2 * co) - w * d) * ch + (w + 2 * o) * (d + 2 * o) * rt
    assert solid_volume(models["townhouse"]) == pytest.approx(volume * METRES_PER_UNIT ** 3, rel=1e-4)
    ground = sum(np.linalg.norm(0.5 * np.cross(_points(models["townhouse"])[s[0]],
                                               np.roll(_points(models["townhouse"])[s[0]], -1, 0)).sum(0))
                 for s, kind in _surfaces(models["townhouse"]) if kind == "GroundSurface")
    assert ground == pytest.approx(w * d * METRES_PER_UNIT ** 2, rel=1e-4)
    attrs = models["townhouse"]["CityObjects"]["building"]["attributes"]
    assert attrs["roof:shape"] == "flat" and attrs["building:levels"] == 4 and attrs["roof:height"] == 0.0


def test_pitched_roofs_keep_their_shape_and_height(models):
    for name, shape in (("house", "gabled"), ("villa", "hipped")):
        attrs = models[name]["CityObjects"]["building"]["attributes"]
        x = GEN.spec.as_dict(CASES[name])
        assert attrs["roof:shape"] == attrs["roofType"] == shape
        assert attrs["roof:height"] == pytest.approx(x["roof_height"] * METRES_PER_UNIT, abs=1e-3)
        # the ridge: the top of the sloped roof surfaces (not a chimney's), the walls' top plus the roof's height
        pts = _points(models[name])
        slopes = [pts[s[0]] for s, kind in _surfaces(models[name]) if kind == "RoofSurface"
                  and np.ptp(pts[s[0]][:, 2]) > 0.1]
        ridge = max(p[:, 2].max() for p in slopes)
        assert len(slopes) == (2 if shape == "gabled" else 4)
        top = x["floors"] * x["floor_height"] + x["ground_extra"]
        assert ridge == pytest.approx((top + x["roof_height"]) * METRES_PER_UNIT, abs=2e-3)


@pytest.mark.slow
def test_level_three_has_a_window_surface_per_window_and_the_doors():
    """The tower at level 3 (frames round every opening, no mullions): one ``Window`` per window,
    the entrances' ``Door`` surfaces, still one closed solid (the boolean's zero-area slivers
    folded into their neighbours' rings)."""
    doc = GEN.city_model(CASES["tower"], 3)
    assert schema_errors(doc) == [] and _closed(doc, "building-part-0")
    assert doc["CityObjects"]["building-part-0"]["geometry"][0]["lod"] == "3"
    kinds = Counter(kind for _, kind in _surfaces(doc))
    x = GEN.spec.as_dict(CASES["tower"])
    per_floor = sum(x[f"windows_{f}"] for f in ("front", "back", "left", "right"))
    assert x["window_split"] == 0 and kinds["Window"] == x["floors"] * per_floor
    assert kinds["Door"] >= x["entrances"] and kinds["GroundSurface"] == 1


def test_generate_writes_cityjson_and_refuses_other_classes(tmp_path, capsys):
    from ipm.cli import main

    params = tmp_path / "params.json"
    params.write_text(json.dumps({"generator": "buildings", "params": GEN.spec.as_dict(CASES["villa"])}))
    out = tmp_path / "villa.city.json"
    assert main(["generate", "--generator", "buildings", "--params", str(params), "--out", str(out)]) == 0
    assert schema_errors(json.loads(out.read_text())) == [] and "surfaces" in capsys.readouterr().out
    for args, message in (
            (["--generator", "dishes", "--params", str(tmp_path / "cup.json"), "--out", str(tmp_path / "cup.json")],
             "dishes has no city model"),
            (["--generator", "buildings", "--params", str(params), "--out", str(tmp_path / "w.json"), "--world"],
             "drop --world"),
            (["--generator", "buildings", "--params", str(params), "--out", str(tmp_path / "v.glb"), "--format",
              "cityjson"], "matching --format")):
        (tmp_path / "cup.json").write_text("{}")
        assert main(["generate", *args]) != 0
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "w.json").exists() and not (tmp_path / "v.glb").exists()


def test_a_buildings_result_carries_its_city_model(tmp_path):
    from ipm.methods.results import CITY_MODEL, write_result

    for generator in ("buildings", "dishes"):
        gen = get_generator(generator)
        x = next(iter(gen.presets.values()))
        info = {"generator": generator, "params": gen.spec.as_dict(x)}
        write_result(tmp_path / generator, gen.mesh(x, 1), info, {"seconds": 1.0})
        written = tmp_path / generator / CITY_MODEL
        assert written.is_file() == (generator == "buildings")
    assert schema_errors(json.loads((tmp_path / "buildings" / CITY_MODEL).read_text())) == []
