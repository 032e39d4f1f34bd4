"""CityJSON 2.0 out: a building as city models exchange it (a ``Building`` with a ``BuildingPart``
per wing, each one closed ``Solid`` at LoD 2.2 with ground, wall and roof surfaces).

The generator's closed solids (walls, cornice, roof, chimney) are joined into one watertight shell
by a real mesh boolean (manifold3d); the shell's triangles are merged back into the planar
polygons they came from, each with its outer ring counter-clockwise seen from outside and its
holes clockwise; vertices are integers (millimetres) under the file's ``transform``. The frame is
CityJSON's: z up, metres (a generator unit is 10 m), the object's frame otherwise (ground at z = 0).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ipm.errors import UserError

SCHEMA = Path(__file__).with_name("schemas") / "cityjson-2.0.2.min.schema.json"
"""The CityJSON 2.0.2 schema (cityjson/specs, CC0), kept here: nothing is downloaded at run time."""
METRES_PER_UNIT = 10.0
MILLIMETRE = 0.001
_Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""Object frame (x, y up, z towards the entrance) to CityJSON's (x, y, z up), right-handed."""


def _closed_solids(vertices: np.ndarray, faces: np.ndarray, roles: np.ndarray, role_of: dict) -> list:
    """manifold3d solids of the closed solids of ``faces`` (each edge-connected set of faces one
    solid), each solid's role (``roles``, per face) recorded in ``role_of`` by its original id."""
    import manifold3d as mf
    import trimesh

    labels = trimesh.graph.connected_component_labels(trimesh.Trimesh(vertices, faces, process=False).face_adjacency,
                                                      node_count=len(faces))
    solids = []
    for k in np.unique(labels):
        tri = faces[labels == k]
        used, local = np.unique(tri, return_inverse=True)
        solid = mf.Manifold(mf.Mesh(vert_properties=np.asarray(vertices[used], np.float32),
                                    tri_verts=local.reshape(-1, 3).astype(np.uint32)))
        if solid.status() != mf.Error.NoError:
            raise ValueError(f"solid {k} is not closed: {solid.status()}")
        solid = solid.as_original()
        role_of[solid.original_id()] = roles[labels == k][0]
        solids.append(solid)
    return solids


def union_shell(vertices: np.ndarray, faces: np.ndarray, roles: np.ndarray, cut=None):
    """One watertight shell from the closed solids of ``faces`` (triangles over ``vertices``) by
    manifold3d's union, less the union of the solids of ``cut`` (faces, roles) if given: its
    vertices, triangles (counter-clockwise seen from outside) and each triangle's role (``roles``,
    per input face, of the solid it came from; a cut face takes the role of the solid that cut it)."""
    import manifold3d as mf

    role_of = {}
    shell = mf.Manifold.batch_boolean(_closed_solids(vertices, faces, roles, role_of), mf.OpType.Add)
    if cut is not None and len(cut[0]):
        shell = shell - mf.Manifold.batch_boolean(_closed_solids(vertices, *cut, role_of), mf.OpType.Add)
    shell = shell.to_mesh()
    tri = np.asarray(shell.tri_verts, np.int64)
    tri_role = np.empty(len(tri), object)
    starts = np.asarray(shell.run_index, np.int64) // 3
    for r, original in enumerate(np.asarray(shell.run_original_id)):
        tri_role[starts[r]:starts[r + 1]] = role_of[int(original)]
    return np.asarray(shell.vert_properties, np.float64)[:, :3], tri, tri_role


def _planes(v: np.ndarray, tri: np.ndarray, keys: np.ndarray, tol: float = 1e-5) -> np.ndarray:
    """A plane id per triangle: triangles with the same key whose planes agree (normals within
    1e-4, offsets within ``tol``) share one."""
    n = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    d = np.einsum("ij,ij->i", n, v[tri[:, 0]])
    _, key = np.unique(keys.astype(str), return_inverse=True)
    pn, pd, pk = np.empty((len(tri), 3)), np.empty(len(tri)), np.empty(len(tri), np.int64)  # the planes so far
    out, count = np.empty(len(tri), np.int64), 0
    for i in range(len(tri)):
        hit = np.flatnonzero((pk[:count] == key[i]) & (pn[:count] @ n[i] > 1 - 1e-4) & (np.abs(pd[:count] - d[i]) < tol))
        if len(hit):
            out[i] = hit[0]
        else:
            pn[count], pd[count], pk[count], out[i] = n[i], d[i], key[i], count
            count += 1
    return out


def _rings(tri: np.ndarray) -> list[list[int]]:
    """The boundary loops of a set of triangles (directed edges whose reverse is not in the set),
    each in the triangles' own direction."""
    edges = {(int(a), int(b)) for t in tri for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    nxt: dict[int, list[int]] = {}
    for a, b in edges:
        if (b, a) not in edges:
            nxt.setdefault(a, []).append(b)
    rings = []
    while nxt:
        start = next(iter(nxt))
        ring, a = [start], start
        while True:
            b = nxt[a].pop()
            if not nxt[a]:
                del nxt[a]
            if b == start:
                break
            ring.append(b)
            a = b
        rings.append(ring)
    return rings


def _vector_area(points: np.ndarray) -> np.ndarray:
    return 0.5 * np.cross(points, np.roll(points, -1, axis=0)).sum(0)


def polygons(v: np.ndarray, tri: np.ndarray, tri_role: np.ndarray) -> list[tuple[list[list[int]], str, np.ndarray]]:
    """The shell's planar polygons: (rings, role, unit normal) per edge-connected set of coplanar
    triangles of one role; the outer ring (largest area) first, counter-clockwise about the normal.
    A triangle without area (three points on a line, left by the boolean) is no polygon: its middle
    point goes into the ring that walks its long edge the other way, so the rings still meet edge
    to edge."""
    import trimesh

    area = np.linalg.norm(np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]]), axis=1)
    flat = area <= 1e-9 * max(float(np.ptp(v, axis=0).max()), 1e-12) ** 2
    plane = _planes(v, tri, tri_role)
    out = []
    for p in np.unique(plane[~flat]):
        sel = np.flatnonzero((plane == p) & ~flat)
        adjacency = trimesh.Trimesh(v, tri[sel], process=False).face_adjacency
        parts = trimesh.graph.connected_component_labels(adjacency, node_count=len(sel))
        for k in np.unique(parts):
            group = tri[sel[parts == k]]
            normal = sum(_vector_area(v[t]) for t in group)
            normal = normal / np.linalg.norm(normal)
            rings = sorted(_rings(group), key=lambda r: -abs(_vector_area(v[r]) @ normal))
            out.append((rings, tri_role[sel[0]], normal))
    for t in tri[flat]:
        a, b = max(((t[i], t[(i + 1) % 3]) for i in range(3)), key=lambda e: np.linalg.norm(v[e[0]] - v[e[1]]))
        middle = int(next(i for i in t if i not in (a, b)))
        for rings, _, _ in out:
            for ring in rings:
                for i in range(len(ring)):
                    if (ring[i], ring[(i + 1) % len(ring)]) == (b, a):
                        ring.insert(i + 1, middle)
                        break
    return out


def surface_type(role: str, normal: np.ndarray, lowest: float, height: float) -> str:
    """CityJSON's semantic surface of a polygon of ``role`` ('wall', 'roof', 'window' or 'door')
    facing ``normal`` (object frame, y up) whose lowest point is at ``height`` (``lowest``: the
    shell's)."""
    if role in ("window", "door"):
        return role.capitalize()
    if normal[1] < -0.99 and height - lowest < 1e-6:
        return "GroundSurface"
    if normal[1] < -0.05:
        return "OuterCeilingSurface"  # eaves' and cornices' undersides
    if normal[1] > 0.05:
        return "RoofSurface" if role == "roof" else "OuterFloorSurface"
    return "WallSurface"


def city_model(vertices: np.ndarray, parts: list[tuple[np.ndarray, np.ndarray, dict]], attributes: dict,
               title: str = "ipm building", lod: str = "2.2") -> dict:
    """A CityJSON 2.0 document: one ``Building`` (with ``attributes``) with a ``BuildingPart`` per
    entry of ``parts`` (faces over ``vertices``, object frame, generator units; each face's role:
    'wall', 'roof', 'window' or 'door'; the part's attributes): the union of its closed solids
    less the earlier parts', as a semantic ``Solid`` at ``lod``; a part left empty is dropped."""
    shells, before = [], (np.zeros((0, 3), np.int64), np.zeros(0, object))
    for faces, roles, part_attributes in parts:
        v, tri, tri_role = union_shell(vertices, faces, roles, cut=before)
        before = (np.concatenate([before[0], faces]), np.concatenate([before[1], roles]))
        if len(tri):
            shells.append((v, tri, tri_role, part_attributes))
    everything = np.concatenate([v for v, *_ in shells])
    city = (everything @ _Y_UP_TO_Z_UP.T) * METRES_PER_UNIT
    translate = city.min(0)
    ints = np.round((city - translate) / MILLIMETRE).astype(np.int64)
    ints, remap = np.unique(ints, axis=0, return_inverse=True)  # vertices within a millimetre merged
    remap, offset = remap.ravel(), 0
    lowest = everything[:, 1].min()
    objects = {"building": {"type": "Building", "attributes": dict(attributes),
                            "children": [f"building-part-{k}" for k in range(len(shells))]}}
    for k, (v, tri, tri_role, part_attributes) in enumerate(shells):
        surfaces, kinds, values = [], [], []
        for rings, role, normal in polygons(v, tri, tri_role):
            kept = []
            for ring in rings:
                ids = [int(remap[offset + i]) for i in ring]
                ids = [a for a, b in zip(ids, ids[1:] + ids[:1]) if a != b]
                if len(ids) >= 3:
                    kept.append(ids)
            if not kept:
                continue
            kind = surface_type(role, normal, lowest, float(v[rings[0], 1].min()))
            if kind not in kinds:
                kinds.append(kind)
            surfaces.append(kept)
            values.append(kinds.index(kind))
        offset += len(v)
        objects[f"building-part-{k}"] = {
            "type": "BuildingPart", "parents": ["building"], "attributes": dict(part_attributes),
            "geometry": [{"type": "Solid", "lod": lod, "boundaries": [surfaces],
                          "semantics": {"surfaces": [{"type": t} for t in kinds], "values": [values]}}]}
    return {"type": "CityJSON", "version": "2.0",
            "transform": {"scale": [MILLIMETRE] * 3, "translate": [float(t) for t in translate]},
            "metadata": {"title": title}, "CityObjects": objects, "vertices": ints.tolist()}


def schema_errors(doc: dict) -> list[str]:
    """Where ``doc`` breaks the CityJSON 2.0 schema (empty: valid)."""
    import jsonschema

    schema = json.loads(SCHEMA.read_text())
    validator = jsonschema.Draft7Validator(schema)
    return [f"{'/'.join(map(str, e.absolute_path)) or '(document)'}: {e.message}" for e in validator.iter_errors(doc)]


def solid_volume(doc: dict, obj: str = "building-part-0") -> float:
    """Volume (cubic metres) enclosed by ``obj``'s first Solid, from its polygons alone."""
    t = doc["transform"]
    pts = np.asarray(doc["vertices"], np.float64) * t["scale"] + t["translate"]
    total = 0.0
    for surface in doc["CityObjects"][obj]["geometry"][0]["boundaries"][0]:
        area = sum(_vector_area(pts[ring]) for ring in surface)
        total += pts[surface[0][0]] @ area / 3.0
    return float(total)


def write_city_json(path: str | Path, doc: dict) -> None:
    """Write ``doc`` to ``path`` atomically, refusing a document the schema does not accept."""
    from ipm.io import write_json

    errors = schema_errors(doc)
    if errors:
        raise UserError(f"not valid CityJSON 2.0 ({len(errors)} errors), first: {errors[0]}")
    write_json(path, doc)
