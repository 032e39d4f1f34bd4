"""Benchmark: a given mask refined by its image (``ipm.segment.refine_mask``). Each case's input view
(256 px, as the mask-robustness bench renders it) with its true mask and with each of
``ipm.degrade``'s degradations, and the segmentation bench's photographs with their true masks, are
refined at each band; every mask is scored by its IoU with the true one, per class and family.

    .venv/bin/python bench/mask_refine.py [--cases cup_1 tree_1] [--bands 3 6] [--photos]
        [--out results/bench/mask_refine.json]

Tune nothing on test cases: the defaults are the dev cups, buildings and trees.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from segmentation import DEV as DEV_PHOTOS, photograph, score  # noqa: E402

DEV = DEV_PHOTOS + ["tree_1", "tree_2", "tree_ext"]


def case_row(case: str) -> dict:
    from ipm.synth import load_case

    spec = load_case(case)
    kind = {"dishes": "cups", "buildings": "buildings"}.get(spec["generator"], "trees")
    return {"case": case, "class": kind, "family": "in" if "generator" in spec["source"] else "out"}


def input_view(case: str, folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """The case's input view (256 px, 32 samples a pixel) as uint8 RGB and its true mask."""
    from PIL import Image

    from ipm.synth import synthesize

    synthesize(case, folder, n_views=1, res=256, spp=32, progress=False)
    frame = json.loads((folder / "transforms.json").read_text())["frames"][0]
    with Image.open(folder / frame["file_path"]) as img:
        rgb = np.asarray(img.convert("RGB"))
    with Image.open(folder / frame["mask_path"]) as img:
        return rgb, np.asarray(img.convert("L")) > 127


def means(rows: list[dict], keys: list[str]) -> dict:
    """Mean mask IoU of each key over all rows and per class and family."""
    groups = {"all": rows}
    for r in rows:
        groups.setdefault(f"{r['class']} {r['family']}", []).append(r)
    return {g: {k: round(float(np.mean([r[k] for r in rs])), 4) for k in keys} | {"n": len(rs)}
            for g, rs in groups.items()}


def main(argv: list[str] | None = None) -> None:
    from tqdm import tqdm

    from ipm.degrade import DEGRADATIONS, degrade
    from ipm.io import write_json
    from ipm.render.photo_scene import BACKDROPS
    from ipm.runtime import configure_threads, machine_info, set_mitsuba_variant
    from ipm.segment import refine_mask

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEV)
    ap.add_argument("--bands", nargs="+", type=float, default=[3.0, 6.0])
    ap.add_argument("--photos", action="store_true", help="score the photographs (the photo layout) instead")
    ap.add_argument("--spp", type=int, default=128, help="samples a pixel of the photographs")
    ap.add_argument("--out", default="results/bench/mask_refine.json")
    args = ap.parse_args(argv)
    configure_threads(1, "cpu")
    set_mitsuba_variant("cpu", 1)
    keys = ["given"] + [f"band {b:g}" for b in args.bands]
    views, photos = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for case in tqdm(args.cases, desc="cases"):
            row = case_row(case)
            if args.photos:
                if row["class"] == "trees":
                    continue
                for backdrop in BACKDROPS:
                    rgb, truth = photograph(case, backdrop, 256, args.spp)
                    r = {**row, "backdrop": backdrop, "given": 1.0}
                    for b, k in zip(args.bands, keys[1:]):
                        r[k] = round(score(refine_mask(rgb, truth, b), truth), 4)
                    photos.append(r)
                continue
            rgb, truth = input_view(case, Path(tmp) / case)
            for name in DEGRADATIONS:
                given = degrade(truth, name, np.random.default_rng([0, 0]))
                r = {**row, "degradation": name, "given": round(score(given.astype(np.float32), truth), 4)}
                for b, k in zip(args.bands, keys[1:]):
                    r[k] = round(score(refine_mask(rgb, given, b), truth), 4)
                views.append(r)
    out = {"machine": machine_info(1), "bands": args.bands, "views": views, "photos": photos}
    if views:
        out["true masks"] = means([r for r in views if r["degradation"] == "none"], keys)
        out["degraded masks"] = means([r for r in views if r["degradation"] != "none"], keys)
        for name in DEGRADATIONS:
            out.setdefault("by degradation", {})[name] = means([r for r in views if r["degradation"] == name], keys)["all"]
    if photos:
        out["photographs, true masks"] = means(photos, keys)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, out)
    for title in ("true masks", "degraded masks", "photographs, true masks"):
        for group, by in out.get(title, {}).items():
            print(f"{title:24s} {group:14s}", "  ".join(f"{k} {by[k]:.4f}" for k in keys), f"(n {by['n']})")
    for name, by in out.get("by degradation", {}).items():
        print(f"{name:16s}", "  ".join(f"{k} {by[k]:.4f}" for k in keys))


if __name__ == "__main__":
    main()
