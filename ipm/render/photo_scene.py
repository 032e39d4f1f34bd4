"""Photograph-like renders of an object with Mitsuba: it stands on a ground surface in sky light
and sunlight, casting its shadow there, in front of one of :data:`BACKDROPS`.

The scene: a sky (an equirectangular gradient, zenith blue to a pale horizon) and a sun (a
directional light from a seeded direction 35-65 degrees high) light the object, which wears its
case's materials (each part its own texture) or a plain colour; the ground is a large plane at the
object's lowest point, with the backdrop's material; ``table`` adds a wall behind the object. Path
traced (paths of up to four segments), so the object's contact shadow and its shading are in the
image; the caller writes it as JPEG.
"""
from __future__ import annotations

import numpy as np

from ipm.render.cameras import sensor_dict

BACKDROPS = ("gradient", "table", "floor")
"""What the object stands on and in front of: ``gradient`` (a pale, slightly mottled studio floor
under the sky's gradient), ``table`` (a wooden table top and a painted wall behind it), ``floor``
(a floor of irregular tiles reaching to the horizon). ``random`` (training only) draws a ground
of random colours and patterns, and a wall half the time."""


def ground_texture(backdrop: str, rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """The ground's colour texture (size, size, 3), linear RGB in [0, 1]."""
    y, x = np.mgrid[0:size, 0:size] / size
    if backdrop == "table":  # wood: warm stripes bent by low-frequency noise
        bend = sum(rng.normal() * np.sin(2 * np.pi * (k * y + rng.random())) for k in (1, 2, 3)) * 0.02
        grain = 0.5 + 0.5 * np.sin(2 * np.pi * 28 * (x + bend))
        base = np.array([0.38, 0.2, 0.09]) * rng.uniform(0.8, 1.2)
        return np.clip(base * (0.75 + 0.35 * grain[..., None]), 0, 1)
    if backdrop == "floor":  # tiles: one shade per tile, dark grout between them
        n = 8
        shades = rng.uniform(0.25, 0.5, (n, n))[..., None] * np.array([1.0, 0.95, 0.85])
        tile = shades[(y * n).astype(int) % n, (x * n).astype(int) % n]
        grout = (np.minimum((x * n) % 1, (y * n) % 1) < 0.05)[..., None]
        return np.where(grout, 0.08, tile)
    if backdrop == "gradient":
        mottle = rng.random((16, 16))
        mottle = np.kron(mottle, np.ones((size // 16, size // 16)))
        return np.clip(np.full((size, size, 3), 0.55) * (0.95 + 0.1 * mottle[..., None]), 0, 1)
    if backdrop == "random":  # two random colours mixed by noise, stripes or checks of a random scale
        a, b = rng.uniform(0.03, 0.8, 3), rng.uniform(0.03, 0.8, 3)
        n = int(rng.choice([2, 4, 8, 16, 32]))
        kind = rng.integers(3)
        if kind == 0:
            t = np.kron(rng.random((n, n)), np.ones((size // n, size // n)))
        elif kind == 1:
            t = 0.5 + 0.5 * np.sin(2 * np.pi * n * (x * np.cos(rng.uniform(0, np.pi)) + y * rng.uniform(-1, 1)))
        else:
            t = ((np.floor(x * n) + np.floor(y * n)) % 2).astype(float)
        t = np.clip(t + rng.normal(0, 0.08, (size, size)), 0, 1)
        return a * (1 - t[..., None]) + b * t[..., None]
    raise ValueError(f"unknown backdrop {backdrop!r} (known: {', '.join(BACKDROPS)})")


def sky(height: int = 64) -> np.ndarray:
    """An equirectangular sky (height, 2 height, 3): zenith blue, pale horizon, grey below it."""
    t = (np.arange(height) + 0.5) / height  # 0 at the zenith, 1 at the nadir
    up = np.clip(1 - 2 * t, 0, 1)[:, None]
    colour = (1 - up) * np.array([0.85, 0.88, 0.92]) + up * np.array([0.35, 0.5, 0.85])
    colour = np.where((t > 0.5)[:, None], np.array([0.3, 0.3, 0.3]), colour)
    return np.repeat(colour[:, None, :], 2 * height, axis=1).astype(np.float32)


def sun_direction(rng: np.random.Generator) -> np.ndarray:
    """The direction sunlight travels (unit, downwards), from a seeded height and heading."""
    el, az = np.radians(rng.uniform(35, 65)), rng.uniform(0, 2 * np.pi)
    return -np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])


def _bitmap(texture: np.ndarray, scale: float = 1.0):
    import mitsuba as mi

    return {"type": "bitmap", "bitmap": mi.Bitmap(texture.astype(np.float32)), "filter_type": "bilinear",
            "wrap_mode": "repeat", "raw": True, "to_uv": mi.ScalarTransform4f().scale([scale, scale, 1])}


def _object_shapes(vertices, faces, uv, texture, plain, labels) -> dict:
    """The object's Mitsuba meshes: one in the ``plain`` colour or wearing one ``texture`` image
    on every face, or (``texture`` a dict, with ``labels``) each part wearing its own, as the
    reference views' parts do (``ipm.render.textured.painted_shapes``)."""
    import mitsuba as mi

    from ipm.render.textured import painted_shapes, unweld

    if isinstance(texture, dict) and plain is None:
        if labels is None:
            raise ValueError("textures per part need the faces' part labels")
        return painted_shapes(vertices, faces, labels, uv, texture)
    v, f, t = unweld(np.asarray(vertices), np.asarray(faces), np.asarray(uv))
    reflectance = {"type": "rgb", "value": list(plain)} if plain is not None else _bitmap(texture)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": reflectance})
    mesh = mi.Mesh("object", len(v), len(f), has_vertex_texcoords=True, props=props)
    mp = mi.traverse(mesh)
    mp["vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
    mp["faces"] = mi.UInt32(f.astype(np.uint32).ravel())
    mp["vertex_texcoords"] = mi.Float(t.astype(np.float32).ravel())
    mp.update()
    return {"object": mesh}


def scene_dict(vertices, faces, uv, c2w: np.ndarray, fov_x: float, width: int, height: int,
               backdrop: str, seed: int, texture: np.ndarray | dict | None, plain: tuple | None = None,
               labels=None) -> dict:
    """The photo's Mitsuba scene (one sensor per camera of ``c2w``): the object with ``texture``
    (one image, or per part label a dict of them with the faces' ``labels``) or the ``plain``
    colour on the backdrop's ground, lit by the sky and a seeded sun."""
    import mitsuba as mi

    rng = np.random.default_rng(seed)
    points = np.asarray(vertices)
    lo, hi = points.min(0), points.max(0)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
    T = mi.ScalarTransform4f
    ground_size = 60 * radius
    sky_scale, sun = (0.8, 1.0) if backdrop != "random" else (rng.uniform(0.4, 1.6), rng.uniform(0.2, 1.5))
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 4},
             **_object_shapes(vertices, faces, uv, texture, plain, labels),
             "sky": {"type": "envmap", "bitmap": mi.Bitmap(sky()), "scale": sky_scale},
             "sun": {"type": "directional", "direction": sun_direction(rng).tolist(),
                     "irradiance": {"type": "rgb", "value": (sun * np.array([3.0, 2.85, 2.6])).tolist()}},
             "ground": {"type": "rectangle",
                        "to_world": T().translate([float(centre[0]), float(lo[1]) - 1e-4, float(centre[2])])
                        @ T().rotate([1, 0, 0], -90) @ T().scale(ground_size),
                        "bsdf": {"type": "diffuse", "reflectance": _bitmap(ground_texture(backdrop, rng),
                                                                           ground_size / (2 * radius))}}}
    if backdrop == "table" or (backdrop == "random" and rng.random() < 0.5):  # a wall behind, square to the view
        ahead = centre - np.asarray(c2w[0])[:3, 3]
        ahead = np.array([ahead[0], 0.0, ahead[2]]) / max(np.hypot(ahead[0], ahead[2]), 1e-9)
        at = centre + ahead * radius * rng.uniform(2.0, 3.5)
        wall = rng.uniform(0.55, 0.8) * np.array([0.95, 0.9, 0.8]) if backdrop == "table" else rng.uniform(0.05, 0.9, 3)
        scene["wall"] = {"type": "rectangle",
                         "to_world": T().look_at(origin=[float(at[0]), float(lo[1] + 10 * radius), float(at[2])],
                                                 target=[float(centre[0]), float(lo[1] + 10 * radius), float(centre[2])],
                                                 up=[0, 1, 0]) @ T().scale(ground_size / 2),
                         "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": wall.tolist()}}}
    for i, m in enumerate(c2w):
        scene[f"sensor_{i:03d}"] = sensor_dict(m, fov_x, width, height)
    return scene


def render_photo(vertices, faces, uv, c2w: np.ndarray, fov_x: float, width: int, height: int,
                 backdrop: str = "table", seed: int = 0, texture: np.ndarray | dict | None = None,
                 plain: tuple | None = None, spp: int = 64, labels=None) -> np.ndarray:
    """Linear RGB photographs (n, height, width, 3) of the object from each camera of ``c2w``
    (:func:`scene_dict`), exposed so the lit ground and sky sit below white."""
    import mitsuba as mi

    scene = mi.load_dict(scene_dict(vertices, faces, uv, c2w, fov_x, width, height, backdrop, seed, texture,
                                    plain, labels))
    images = np.stack([np.array(mi.render(scene, sensor=i, spp=spp, seed=(seed * 1000 + i) % 2**32))
                       for i in range(len(c2w))])
    return np.clip(images * 0.8 / max(float(np.quantile(images, 0.99)), 1e-6), 0.0, 1.0)
