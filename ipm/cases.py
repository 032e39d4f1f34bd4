"""The benchmark's case splits, and the seeded sampler of in-family cases.

Every case file (``datasets_synthetic/NAME.json``) says its split:

- ``dev``: cases on which defaults, priors and budgets may be tuned;
- ``test``: cases scored, never looked at while choosing a setting: in-family objects drawn by
  :func:`sample_case` from a generator's parameter space (``Generator.sample``, not from presets),
  each at least :data:`MIN_PRESET_DISTANCE` from every preset, at random poses and camera
  elevations; and out-of-family objects built by independent code (``datasets_synthetic.recipes``).

The dev split holds sampled cups too (other sampler seeds), so that tuning sees the kind of
object the test split scores.

``python -m ipm.cases`` writes the sampled case files from :data:`SAMPLED` (they are committed;
a test checks that the sampler still draws them).
"""
from __future__ import annotations

import json
import sys
from importlib import resources
from pathlib import Path

import numpy as np

from ipm.errors import UserError


def list_cases() -> list[str]:
    """The names of the case files in ``datasets_synthetic``, sorted."""
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


SPLITS = ("dev", "test")
MIN_PRESET_DISTANCE = 0.3
"""Least unit-cube distance (largest coordinate, :func:`unit_distance`) from a sampled case to
every preset of its generator."""
MAX_TRIANGLES = 300_000
"""Sampled objects with more triangles at the reference's level of detail are drawn again (the
metric ray-casts every reference 64 times and voxelises it)."""
ELEVATION_RANGE = (10.0, 35.0)
"""Camera elevation of a sampled case's input view (degrees)."""
FOV_RANGE = (25.0, 75.0)
"""Horizontal field of view (degrees) of the cases that draw their lens (``fov_drawn``): from a
phone's 3x telephoto to its main camera held landscape, geometric in tan(fov / 2). The other cases
keep :data:`ipm.synth.FOV_X`."""
SAMPLED = (
    ("cup_t1", "dishes", 1001, {"handle": True}, "test"),
    ("cup_t2", "dishes", 1002, {"handle": False}, "test"),
    ("cup_t3", "dishes", 1003, {"handle": True}, "test"),
    ("cup_t4", "dishes", 1004, {"handle": False}, "test"),
    ("tree_t1", "trees", 2001, {}, "test"),
    ("tree_t2", "trees", 2002, {}, "test"),
    ("tree_t3", "trees", 2003, {}, "test"),
    ("tree_t4", "trees", 2004, {}, "test"),
    ("building_t1", "buildings", 4001, {}, "test"),
    ("building_t2", "buildings", 4002, {}, "test"),
    ("building_t3", "buildings", 4003, {}, "test"),
    ("building_t4", "buildings", 4004, {}, "test"),
    ("building_d1", "buildings", 5001, {}, "dev"),
    ("building_d2", "buildings", 5002, {}, "dev"),
    ("building_d3", "buildings", 5003, {}, "dev"),
    ("building_d4", "buildings", 5005, {}, "dev"),
    ("building_d5", "buildings", 5006, {}, "dev"),
    ("building_d6", "buildings", 5007, {}, "dev"),
    ("building_d7", "buildings", 5008, {}, "dev"),
    ("building_d8", "buildings", 5009, {}, "dev"),
    ("building_d9", "buildings", 5010, {}, "dev"),
    ("building_d10", "buildings", 5011, {}, "dev"),
    ("building_d11", "buildings", 5012, {}, "dev"),
    ("building_d12", "buildings", 5013, {}, "dev"),
    ("building_d13", "buildings", 5014, {}, "dev"),
    ("building_d14", "buildings", 5015, {}, "dev"),
    ("building_d15", "buildings", 5017, {}, "dev"),  # 5016 drew a building 2.24 tall (cases: at most 2)
    ("building_d16", "buildings", 5018, {}, "dev"),
    ("building_d17", "buildings", 5019, {}, "dev"),
    ("building_d18", "buildings", 5020, {}, "dev"),
    ("building_d19", "buildings", 5021, {}, "dev"),
    ("building_d20", "buildings", 5022, {}, "dev"),
    ("building_d21", "buildings", 5023, {}, "dev"),
    ("building_d22", "buildings", 5024, {}, "dev"),
    ("building_d23", "buildings", 5025, {}, "dev"),
    ("building_d24", "buildings", 5026, {}, "dev"),
    ("building_d25", "buildings", 5027, {}, "dev"),
    ("building_d26", "buildings", 5028, {}, "dev"),
    ("building_d27", "buildings", 5029, {}, "dev"),
    ("building_d28", "buildings", 5030, {}, "dev"),
    ("building_d29", "buildings", 5031, {}, "dev"),
    ("building_d30", "buildings", 5032, {}, "dev"),
    ("building_d31", "buildings", 5033, {}, "dev"),
    ("building_d32", "buildings", 5034, {}, "dev"),
    ("building_d33", "buildings", 5035, {}, "dev"),
    ("building_d34", "buildings", 5036, {}, "dev"),
    ("building_d35", "buildings", 5037, {}, "dev"),
    ("building_d36", "buildings", 5038, {}, "dev"),
    ("building_d37", "buildings", 5039, {}, "dev"),
    ("building_d38", "buildings", 5040, {}, "dev"),
    ("building_d39", "buildings", 5041, {}, "dev"),
    ("building_d40", "buildings", 5042, {}, "dev"),
    ("building_d41", "buildings", 5043, {}, "dev"),
    ("building_d42", "buildings", 5044, {}, "dev"),
    ("cup_d1", "dishes", 3001, {"handle": True}, "dev"),
    ("cup_d2", "dishes", 3002, {"handle": True}, "dev"),
    ("cup_d3", "dishes", 3003, {"handle": True, "fov_drawn": True}, "dev"),
    ("cup_d4", "dishes", 3004, {"handle": False, "fov_drawn": True}, "dev"),
    ("building_d43", "buildings", 5045, {"fov_drawn": True}, "dev"),
    ("building_d44", "buildings", 5046, {"fov_drawn": True}, "dev"),
    ("cup_t5", "dishes", 1005, {"handle": True, "fov_drawn": True}, "test"),
    ("cup_t6", "dishes", 1006, {"handle": False, "fov_drawn": True}, "test"),
    ("building_t5", "buildings", 4005, {"fov_drawn": True}, "test"),
    ("building_t6", "buildings", 4006, {"fov_drawn": True}, "test"),
)
"""Sampled in-family cases: (name, generator, sampler seed, sampler options, split). The test
cups alternate with and without a handle, so both topologies are scored; the dev split has
sampled cups too, so settings are tuned on objects of the kind the test split scores. The cases
with ``fov_drawn`` also draw their camera's field of view from :data:`FOV_RANGE` (the rest are
rendered at 39.6 degrees), so that a field of view estimated from a photo is scored away from it."""


def unit_distance(generator, x: np.ndarray, y: np.ndarray) -> float:
    """Largest difference of two parameter vectors in the unit cube, over the parameters that
    shape either object (``Generator.active``), without ``Generator.distance_ignores``."""
    spec = generator.spec
    on = generator.active(x) | generator.active(y)
    for name in generator.distance_ignores:
        on[spec.index[name]] = False
    d = np.abs(spec.to_unit(spec.clip(x)) - spec.to_unit(spec.clip(y)))
    return float(d[on].max()) if on.any() else 0.0


def preset_distances(generator, x: np.ndarray) -> dict[str, float]:
    """:func:`unit_distance` from ``x`` to each preset of ``generator``."""
    return {name: round(unit_distance(generator, x, p), 4) for name, p in sorted(generator.presets.items())}


def sample_case(name: str, generator: str, seed: int, split: str = "test", fov_drawn: bool = False,
                **options) -> dict:
    """A ``split`` case drawn from ``generator``'s family with ``seed``: parameters from
    ``Generator.sample(rng, **options)``, drawn again while nearer than
    :data:`MIN_PRESET_DISTANCE` to a preset or larger than :data:`MAX_TRIANGLES`; then a pose
    (yaw 0-360 degrees, offsets up to 0.1, scale 0.85-1.15), an input camera (any azimuth,
    elevation in :data:`ELEVATION_RANGE`) and, with ``fov_drawn``, its field of view (last, so
    that the draws before it do not depend on it)."""
    from ipm.generators import get_generator  # JAX's import: only where a case is drawn

    gen = get_generator(generator)
    rng = np.random.default_rng(seed)
    for draw in range(1, 1001):
        x = gen.sample(rng, **options)
        dist = preset_distances(gen, x)
        if min(dist.values()) >= MIN_PRESET_DISTANCE and len(gen.mesh(x, 2).faces) <= MAX_TRIANGLES:
            break
    else:
        raise RuntimeError(f"{name}: no usable draw in 1000")
    nearest = min(dist, key=dist.get)
    case = {
        "name": name,
        "split": split,
        "description": f"A {generator}-family object drawn by the seeded sampler (ipm.cases, seed {seed}), "
                       f"not from a preset: unit-cube distance {dist[nearest]:.2f} to the nearest preset "
                       f"({nearest}).",
        "generator": generator,
        "source": {"generator": generator, "params": gen.spec.as_dict(x)},
        "sampler": {"seed": seed, "options": options, "draws": draw, "preset_distance": dist,
                    "nearest_preset": nearest, "min_preset_distance": dist[nearest]},
        "pose": {"yaw_deg": round(float(rng.uniform(0.0, 360.0)), 2),
                 "translation": [round(float(rng.uniform(-0.1, 0.1)), 4), 0.0, round(float(rng.uniform(-0.1, 0.1)), 4)],
                 "scale": round(float(rng.uniform(0.85, 1.15)), 4)},
        "camera": {"azimuth_deg": round(float(rng.uniform(-180.0, 180.0)), 2),
                   "elevation_deg": round(float(rng.uniform(*ELEVATION_RANGE)), 2)},
    }
    if generator == "dishes":
        case["texture_seed"] = int(rng.integers(100, 1000))
    if fov_drawn:
        lo, hi = np.log(np.tan(np.radians(FOV_RANGE) / 2))
        case["camera"]["fov_deg"] = round(float(np.degrees(2 * np.arctan(np.exp(rng.uniform(lo, hi))))), 2)
        case["sampler"]["fov_drawn"] = True
    return case


def case_split(case: dict) -> str:
    """The split of a case definition (``UserError`` if missing or unknown)."""
    split = case.get("split")
    if split not in SPLITS:
        raise UserError(f"case {case.get('name')!r}: split must be one of {', '.join(SPLITS)}, got {split!r}")
    return split


def case_family(case: dict) -> str:
    """``in`` for a case made by its class's generator, ``out`` for one built by independent code."""
    return "in" if "generator" in case["source"] else "out"


def describe_cases(split: str | None = None) -> str:
    """One line per case (``ipm cases``): name, split, generator, family (in: made by the generator,
    with its distance to the nearest preset; out: the recipe that built it), input elevation and
    field of view."""
    from ipm.synth import case_fov

    lines = [f"{'case':14} {'split':5} {'generator':9} {'family':34} elevation  fov"]
    for name in list_cases():
        case = load_case(name)
        if split is not None and case_split(case) != split:
            continue
        src = case["source"]
        if "recipe" in src:
            family = f"out: {src['recipe']}"
        elif "sampler" in case:
            family = f"in: sampled, {case['sampler']['min_preset_distance']:.2f} from {case['sampler']['nearest_preset']}"
        else:
            family = f"in: preset {src.get('preset', 'defaults')}, edited"
        lines.append(f"{name:14} {case_split(case):5} {case['generator']:9} {family:34} "
                     f"{case.get('camera', {}).get('elevation_deg', 22.0):>5.0f} deg  "
                     f"{np.degrees(case_fov(case)):.1f} deg")
    return "\n".join(lines)


def expand_groups(config: dict) -> dict:
    """A workflow config's ``cases`` and ``methods`` with its case groups written out: ``groups``
    names lists of cases or of other groups, and a group's name in ``cases`` or in a methods
    entry's ``cases`` stands for its cases, in order, each case once (``ValueError`` for a group
    named like a case or one that contains itself)."""
    groups = config.get("groups") or {}
    clash = sorted(set(groups) & set(list_cases()))
    if clash:
        raise ValueError(f"config: groups {', '.join(clash)} are named like cases; rename them")

    def names(items, inside=()):
        out = []
        for item in items:
            if item in inside:
                raise ValueError(f"config: group {item} contains itself ({' -> '.join(inside + (item,))})")
            for case in names(groups[item], inside + (item,)) if item in groups else [item]:
                if case not in out:
                    out.append(case)
        return out

    methods = [{**m, "cases": names(m["cases"])} if "cases" in m else m for m in config.get("methods", [])]
    return {"cases": names(config["cases"]), "methods": methods}


def write_sampled_cases(folder: str | Path) -> list[Path]:
    """Write the :data:`SAMPLED` cases as ``folder/NAME.json``."""
    from ipm.io import write_json

    out = []
    for name, generator, seed, options, split in SAMPLED:
        path = Path(folder) / f"{name}.json"
        write_json(path, sample_case(name, generator, seed, split, **options))
        out.append(path)
    return out


if __name__ == "__main__":  # python -m ipm.cases [FOLDER]: (re)write the sampled case files
    folder = sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "datasets_synthetic"
    from ipm.io.paths import shown_path

    for p in write_sampled_cases(folder):
        print(shown_path(p), json.loads(p.read_text())["sampler"]["min_preset_distance"])
