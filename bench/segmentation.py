"""Benchmark: masks from a photograph. Each case is rendered as a photograph (``ipm.render.photo_scene``:
sky, sun, its shadow on a ground) on every backdrop, from its input camera, with the case's
photo setting (``ipm.synth.photo_setting``: scene seed, texture or plain colour), and JPEG at the
photo layout's quality (with ``--plain``: the ``hemi`` layout's input view instead, the object on
a plain background); each segmenter's mask is scored by its IoU with the true mask, per case and
backdrop, with the means per class and family.

    .venv/bin/python bench/segmentation.py [--cases cup_1 building_1] [--res 256] [--spp 128]
        [--out results/bench/segmentation.json] [--weights SEGMENTER.json ...] [--plain] [--full-size] [--distance K] [--uncropped]

Segmenters: ``colour`` (``ipm.segment.mask_from_image``, the colour model of the border),
``learned`` (``ipm.segment.mask_from_photo``: the shipped segmenter, then GrabCut), ``network``
(the shipped network's probability above 0.5, no GrabCut) and, for each ``--weights`` file,
``learned:STEM`` and ``network:STEM`` (the same with those weights), with ``--held``
``learned:held`` (``mask_from_photo(release=False)``: nothing released), with ``--full-size``
``colour:full`` and ``learned:full`` (photos larger than ``ipm.segment.SEGMENT_PX`` segmented at
their own size, not shrunk to it), with ``--uncropped`` ``learned:uncropped`` (no second look at a
small object), all on the same photographs, with each segmenter's seconds.
Tune nothing on test cases: the defaults are the dev cups and buildings.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

DEV = ["cup_1", "cup_2", "cup_d1", "cup_d2", "cup_d3", "cup_d4", "cup_bowl", "cup_c_mug", "cup_c_mug_steep", "cup_ext",
       "cup_cocktail", "cup_egg", "cup_flute", "cup_stein", "cup_sundae", "cup_teacup",
       "building_1", "building_d3", "building_d9", "building_d11", "building_d20", "building_d25", "building_annex",
       "building_ext", "building_t_house"]


def photograph(case: str, backdrop: str, res: int, spp: int, distance: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The case's input view as a JPEG photograph (res, res, 3) uint8 on ``backdrop``, and its true mask
    (both as its lens draws them); ``distance``: the camera that many times as far from the object's
    middle (a smaller object in the frame)."""
    from ipm.io.views import jpeg_roundtrip, srgb_bytes
    from ipm.cases import load_case
    from ipm.synth import PHOTO_QUALITY, case_cameras, ground_truth_mesh, photographs

    spec = load_case(case)
    v, f, labels, uv = ground_truth_mesh(spec)
    c2w, fov = case_cameras(spec, v, 1, "photo")
    middle = (v.min(0) + v.max(0)) / 2
    c2w[:, :3, 3] = middle + distance * (c2w[:, :3, 3] - middle)
    linear, masks, _ = photographs(case, spec, v, f, labels, uv, c2w, fov, res, spp, backdrop)
    return jpeg_roundtrip(srgb_bytes(linear[0]), PHOTO_QUALITY), masks[0] > 0.5


def plain_view(case: str, res: int, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """The case's input view of the ``hemi`` layout (its reference materials on a plain background,
    as synth writes it: 8-bit sRGB, no alpha) and its true mask."""
    from ipm.io.views import srgb_bytes
    from ipm.render.silhouette import SilhouetteRenderer
    from ipm.render.textured import render_painted
    from ipm.cases import load_case
    from ipm.synth import case_cameras, ground_truth_mesh, reference_appearance

    spec = load_case(case)
    v, f, labels, uv = ground_truth_mesh(spec)
    c2w, fov = case_cameras(spec, v, 1, "hemi")
    rgb = render_painted(v, f, labels, uv, reference_appearance(spec, v, f, labels, uv), c2w, fov, res, res, spp)
    return srgb_bytes(rgb[0]), SilhouetteRenderer(c2w, fov, res, res, spp=16).render(v, f)[0] > 0.5


def network_mask(img: np.ndarray, model=None) -> np.ndarray:
    """The segmenter's network alone (``model``, else the shipped one): its probability above 0.5."""
    from ipm.learned.segmenter import probability

    return (probability(img, model) > 0.5).astype(np.float32)


def full_size(segment, img: np.ndarray) -> np.ndarray:
    """``segment`` (``ipm.segment``'s mask function) on ``img`` at its full size, however large."""
    import ipm.segment

    kept, ipm.segment.SEGMENT_PX = ipm.segment.SEGMENT_PX, 1 << 30
    try:
        return segment(img)
    finally:
        ipm.segment.SEGMENT_PX = kept


def score(mask: np.ndarray, truth: np.ndarray) -> float:
    """The IoU of ``mask > 0.5`` with the true mask."""
    from ipm.metrics.silhouette import view_ious

    return float(view_ious(truth[None], (mask > 0.5)[None])[0])


def summary(rows: list[dict], segmenters: list[str]) -> dict:
    """Mean and worst mask IoU per segmenter over all rows, per class and family, and per backdrop."""
    groups = {"all": rows}
    for r in rows:
        groups.setdefault(f"{r['class']} {r['family']}", []).append(r)
        groups.setdefault(r["backdrop"], []).append(r)
    return {g: {s: {"mean": round(float(np.mean([r[s] for r in rs])), 4), "worst": round(min(r[s] for r in rs), 4),
                    "n": len(rs)} for s in segmenters} for g, rs in groups.items()}


def main(argv: list[str] | None = None) -> None:
    from tqdm import tqdm

    from ipm.cases import case_family
    from ipm.errors import UserError
    from ipm.io import write_json
    from ipm.render.photo_scene import BACKDROPS
    from ipm.runtime import configure_threads, set_mitsuba_variant
    from ipm.learned.segmenter import load
    from ipm.segment import mask_from_image, mask_from_photo
    from ipm.cases import load_case

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEV)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--out", default="results/bench/segmentation.json")
    ap.add_argument("--weights", nargs="*", default=[], help="other weights of the learned segmenter to score beside "
                    "the shipped ones")
    ap.add_argument("--held", action="store_true", help="score the learned path without the object's colours "
                    "releasing what the network took for ground beside it (learned:held)")
    ap.add_argument("--plain", action="store_true", help="score the hemi layout's input view (a plain background) "
                    "instead of the photographs")
    ap.add_argument("--distance", type=float, default=1.0, help="photographs from this many times as far (a "
                    "smaller object in the frame)")
    ap.add_argument("--uncropped", action="store_true", help="also score the learned path without its second look "
                    "at a small object (learned:uncropped)")
    ap.add_argument("--full-size", action="store_true", help="also score colour and learned on photos larger than "
                    "ipm.segment.SEGMENT_PX at their full size (colour:full, learned:full), not shrunk to it")
    args = ap.parse_args(argv)
    configure_threads(1, "cpu")
    set_mitsuba_variant("cpu", 1)
    segmenters = {"colour": mask_from_image, "learned": mask_from_photo, "network": network_mask}
    if args.held:
        segmenters["learned:held"] = lambda img: mask_from_photo(img, release=False)
    if args.uncropped:
        segmenters["learned:uncropped"] = lambda img: mask_from_photo(img, crop=False)
    if args.full_size:
        segmenters["colour:full"] = lambda img: full_size(mask_from_image, img)
        segmenters["learned:full"] = lambda img: full_size(mask_from_photo, img)
    for path in args.weights:
        segmenters[f"learned:{Path(path).stem}"] = lambda img, model=load(path): mask_from_photo(img, model)
        segmenters[f"network:{Path(path).stem}"] = lambda img, model=load(path): network_mask(img, model)
    rows = []
    for case in tqdm(args.cases, desc="cases"):
        spec = load_case(case)
        for backdrop in ("plain",) if args.plain else BACKDROPS:
            rgb, truth = plain_view(case, args.res, args.spp) if args.plain else photograph(case, backdrop, args.res,
                                                                                            args.spp, args.distance)
            row = {"case": case, "backdrop": backdrop, "class": "cups" if spec["generator"] == "dishes" else "buildings",
                   "family": case_family(spec)}
            for name, fn in segmenters.items():
                t0 = time.perf_counter()
                try:
                    row[name] = round(score(fn(rgb), truth), 4)
                except UserError:
                    row[name] = 0.0
                row[f"{name} s"] = round(time.perf_counter() - t0, 3)
            rows.append(row)
    seconds = {name: round(float(np.mean([r[f"{name} s"] for r in rows])), 3) for name in segmenters}
    out = {"res": args.res, "spp": args.spp, "distance": args.distance, "rows": rows, "summary": summary(rows, list(segmenters)),
           "seconds_per_photo": seconds}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, out)
    for group, by in out["summary"].items():
        print(f"{group:16s}", "  ".join(f"{s} {v['mean']:.3f} (worst {v['worst']:.3f}, n {v['n']})" for s, v in by.items()))
    print("seconds a photo:", "  ".join(f"{s} {v:.2f}" for s, v in seconds.items()))
    for name in (n for n in segmenters if ":" in n):  # other weights or sizes against the shipped ones
        d = np.array([r[name] - r[name.split(":")[0]] for r in rows])  # (learned:held: negative where the release helps)
        se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
        print(f"{name} - {name.split(':')[0]}: paired {d.mean():+.4f} (SE {se:.4f}; {(d > 0.005).sum()} better, "
              f"{(d < -0.005).sum()} worse by more than 0.005)")


if __name__ == "__main__":
    main()
