"""Benchmark: appearance. Each case is synthesised with colour views under the reference lighting
(``ipm synth``): the hemi layout's views are the inputs, the held layout's (view 0 the same input
view, the others between any inputs) the scoring views. Ours (the diff path; the GA for
trees) reconstructs it from its first 1 and 6 hemi views and paints its parts from them
(``ipm.texture``); instant-NGP-style (``--ngp N``) fits its radiance field to N of them. Each
result is rendered under the reference lighting (the field as it is) and scored against every held
view (``ipm.metrics.texture``: masked PSNR and SSIM in sRGB) on the input view, the half of the
sphere it sees and the other half.

    .venv/bin/python bench/texture.py [--cases cup_1 cup_2] [--inputs 1 6] [--ngp 16] [--views 16]
        [--seeds 0] [--jobs 2] [--refine none 64:20,256:20] [--texels 256 512] [--repeat 3] [--threads 2]
        [--passes 1 2] [--truth] [--work DIR] [--out results/bench/texture]

A fit runs as ``ipm reconstruct`` / ``ipm baseline ngp`` on one thread, ``--jobs`` at a time;
``--refine`` paints ours' fits again with each refinement (``ipm.texture.Refinement``), one at a
time on ``--threads``, and times the stage; ``--texels`` paints them again (no refinement) at each
texture size, ``--passes`` with each number of projection passes (``ipm.texture.SHADING_PASSES``);
``--truth`` paints each in-family case's ground truth as ours' fits are painted
(row ``truth``: the stage's scores where the shape is right, which tells the shape's share of a
loss from the texture's).
Tune nothing on what it prints for test cases: run it on dev cases (the defaults) to choose, on
test cases to report.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

DEV = ["cup_1", "cup_2", "cup_d1", "cup_bowl", "cup_ext", "cup_c_mug", "building_1", "building_d1", "building_d2",
       "building_ext", "building_annex", "building_t_house"]
"""The dev cases of the texture stage's choices (docs/decisions.md, "Texture refinement")."""
IPM = [sys.executable, "-m", "ipm.cli"]
SCORING = threading.Lock()


def run(args: list[str]) -> None:
    done = subprocess.run(IPM + args, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"ipm {' '.join(args)} failed:\n{done.stderr[-2000:]}")


def one(case: str, work: Path, row: str, n_input: int, seed: int) -> dict:
    """Fit ``case`` with ``row`` (diff: ours, the GA where the generator is not differentiable; or
    ngp) from its first ``n_input`` hemi views and score the result's appearance on its held views."""
    from ipm.generators import get_generator
    from ipm.methods import METHODS
    from ipm.metrics.texture import score_result
    from ipm.cases import load_case

    out = work / f"{case}_{row}{n_input}v_s{seed}"
    views = ["--views", str(work / case / "hemi" / "transforms.json"), "--n-input-views", str(n_input),
             "--seed", str(seed), "--threads", "1", "--out", str(out), "--quiet"]
    if (out / "timing.json").is_file():
        pass  # a kept work folder's fit
    elif row == "diff":  # ours: the diff path, or the GA where the generator is not differentiable
        generator = get_generator(load_case(case)["generator"])
        path = [] if generator.differentiable else [
            "--method", "ga", "--prepared", str(METHODS["ga"].shipped_file(generator.name))]
        run(["reconstruct", "--generator", generator.name, *path, *views])
    else:
        run(["baseline", row, *views])
    info = json.loads((out / ("params.json" if row == "diff" else "info.json")).read_text())
    timing = json.loads((out / "timing.json").read_text())
    with SCORING:  # Dr.Jit's renders are not to be run from two threads of one process at once
        scores = score_result(out, work / case / "held" / "transforms.json", METHODS[row].appearance)
    return {"case": case, "row": row, "inputs": n_input, "seed": seed, "sides": scores["sides"],
            "seen_texels": info.get("texture", {}).get("seen"), "seconds": timing["seconds"],
            "texture_seconds": timing.get("texture_seconds"), "refine": "default"}


def schedule(text: str):
    """A refinement from its spelling: ``none``, or stages ``RES:STEPS,RES:STEPS``."""
    from ipm.texture import Refinement

    if text == "none":
        return None
    return Refinement(stages=tuple(tuple(int(x) for x in stage.split(":")) for stage in text.split(",")))


def repaint(case: str, work: Path, n_input: int, seed: int, variant: str, texels: int | None = None,
            passes: int | None = None) -> dict:
    """Ours' fit of ``case`` painted again with the refinement ``variant`` on textures of ``texels``
    a side and with ``passes`` projections (None: the stage's own) and scored as :func:`one`."""
    from ipm.io.mesh import read_textured_glb

    v, f, labels, uv, _ = read_textured_glb(work / f"{case}_diff{n_input}v_s{seed}" / "mesh.glb")
    label = variant + ("" if texels is None else f", {texels} texels") + ("" if passes is None else f", {passes} passes")
    return {"case": case, "row": "diff", "inputs": n_input, "seed": seed, "refine": label,
            **painted(case, work, n_input, seed, (v, f, labels, uv), variant, texels, passes)}


def truth(case: str, work: Path, n_input: int, passes: int | None = None) -> dict:
    """The case's own ground truth painted by the texture stage from its first ``n_input`` views and
    scored as :func:`one` (row ``truth``): what the stage reaches where the shape is right. In-family
    cases only: the fill's symmetry is the generator's charts'."""
    from ipm.cases import case_family, load_case
    from ipm.errors import UserError
    from ipm.synth import ground_truth_mesh

    spec = load_case(case)
    if case_family(spec) != "in":
        raise UserError(f"{case} is not made by a generator: its charts have no symmetry to fill by")
    return {"case": case, "row": "truth", "inputs": n_input, "seed": 0,
            "refine": "default" if passes is None else f"{passes} passes",
            **painted(case, work, n_input, 0, ground_truth_mesh(spec), None, None, passes)}


def painted(case: str, work: Path, n_input: int, seed: int, mesh: tuple, variant: str | None,
            texels: int | None, passes: int | None = None) -> dict:
    """A mesh (world vertices, faces, part labels, UVs) of ``case``'s generator painted from the case's
    first ``n_input`` hemi views (refinement ``variant``, ``texels`` a side, ``passes`` projections;
    None: the stage's own) and rendered on its held views: the scores per side and the stage's
    seconds."""
    import time

    from ipm.generators import get_generator
    from ipm.generators.base import Mesh
    from ipm.io.views import load_photos, load_views
    from ipm.metrics.texture import score_renders
    from ipm.render.textured import render_painted
    from ipm.cases import load_case
    from ipm.texture import REFINEMENT, SHADING_PASSES, TEXTURE_RES, paint

    gen = get_generator(load_case(case)["generator"])
    v, f, labels, uv = mesh
    views = load_views(work / case / "hemi" / "transforms.json").first(n_input)
    t0 = time.perf_counter()
    textures, _ = paint(gen, Mesh(v, f, np.zeros_like(v), uv, labels, gen.part_names), load_photos(views),
                        views.masks, views.c2w, views.fov_x, views.lighting, res=texels or TEXTURE_RES,
                        refinement=REFINEMENT if variant is None else schedule(variant), seed=seed,
                        passes=passes or SHADING_PASSES)
    seconds = time.perf_counter() - t0
    held = load_views(work / case / "held" / "transforms.json")
    renders = render_painted(v, f, labels, uv, textures, held.c2w, held.fov_x, held.width, held.height)
    return {"sides": score_renders(renders, held)["sides"], "texture_seconds": seconds}


def table(rows: list[dict]) -> str:
    """Markdown: a row per case, method, input count and refinement, PSNR / SSIM per side (mean
    over seeds)."""
    lines = ["| case | row | views in | refinement | input PSNR / SSIM | seen half | unseen half |",
             "|---|---|---|---|---|---|---|"]
    keys = sorted({(r["case"], r["row"], r["inputs"], r["refine"]) for r in rows},
                  key=lambda k: (k[1], k[2], k[3], k[0]))
    for case, row, n, variant in keys:
        mine = [r for r in rows if (r["case"], r["row"], r["inputs"], r["refine"]) == (case, row, n, variant)]
        cells = []
        for side in ("input", "seen", "unseen"):
            got = [r["sides"][side] for r in mine if side in r["sides"]]
            cells.append(f"{np.mean([g['psnr'] for g in got]):.1f} / {np.mean([g['ssim'] for g in got]):.3f}"
                         if got else "-")
        shown = variant if row == "diff" or variant != "default" else "-"
        lines.append(f"| {case} | {row} | {n} | {shown} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=DEV)
    ap.add_argument("--inputs", nargs="+", type=int, default=[1, 6])
    ap.add_argument("--ngp", nargs="*", type=int, default=[], help="instant-NGP-style's input views (none: not run)")
    ap.add_argument("--views", type=int, default=16, help="held (scoring) views per case")
    ap.add_argument("--refine", nargs="*", default=[],
                    help="ours' fits painted again with these refinements (none, or RES:STEPS,RES:STEPS)")
    ap.add_argument("--texels", nargs="*", type=int, default=[],
                    help="texture sizes to paint ours' fits again at (no refinement)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="results/bench/texture")
    ap.add_argument("--work", default=None, help="keep the views and fits here (and reuse those it holds)")
    ap.add_argument("--repeat", type=int, default=1, help="repaints per fit and refinement (for their times)")
    ap.add_argument("--threads", type=int, default=1, help="threads of the repaints (each fit takes one)")
    ap.add_argument("--passes", nargs="*", type=int, default=[],
                    help="projection passes to paint ours' fits again with (no refinement)")
    ap.add_argument("--truth", action="store_true", help="also paint each case's ground truth (row truth; "
                    "in-family cases): the stage's scores where the shape is right")
    args = ap.parse_args()
    from ipm.runtime import configure_threads, set_mitsuba_variant

    configure_threads(args.threads, "cpu")
    set_mitsuba_variant("cpu", args.threads)
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        for case in args.cases:
            if (work / case / "held").is_dir():  # a kept work folder: its views and fits are reused
                continue
            for layout, n in (("hemi", max(args.inputs + args.ngp)), ("held", args.views)):
                run(["synth", "--case", case, "--out", str(work / case / layout), "--views", str(n),
                     "--layout", layout])
        jobs = [(c, work, row, n, s) for row, counts in (("ngp", args.ngp), ("diff", args.inputs))
                for n in counts for c in args.cases for s in args.seeds]
        with ThreadPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(lambda a: one(*a), jobs))
        for variant in args.refine:  # one at a time: their seconds are the stage's own
            rows += [repaint(c, work, n, s, variant) for c in args.cases for n in args.inputs for s in args.seeds
                     for _ in range(args.repeat)]
        for texels in args.texels:
            rows += [repaint(c, work, n, s, "none", texels) for c in args.cases for n in args.inputs
                     for s in args.seeds for _ in range(args.repeat)]
        for passes in args.passes:
            rows += [repaint(c, work, n, s, "none", None, passes) for c in args.cases for n in args.inputs
                     for s in args.seeds for _ in range(args.repeat)]
        if args.truth:  # the cases a generator made (the others' charts have no symmetry to fill by)
            from ipm.cases import case_family, load_case

            made = [c for c in args.cases if case_family(load_case(c)) == "in"]
            rows += [truth(c, work, n, p) for c in made for n in args.inputs for p in [None, *args.passes]]
    from ipm.io.atomic import write_json
    from ipm.runtime import machine_info, machine_line

    machine = machine_line(machine_info(args.threads))  # the fits' and repaints' seconds depend on the CPU's kind
    write_json(out / "texture.json", [{**r, "machine": machine} for r in rows])
    (out / "texture.md").write_text(table(rows) + "\n")
    print(table(rows))


if __name__ == "__main__":
    main()
