"""The README's figure: for each reconstruction, its input view, the fitted parts over it and from
two other sides, and the parameters that make it.

    python scripts/overview_figure.py --run OUT_DIR VIEWS_JSON [--run ...] --out docs/overview.png

``OUT_DIR`` is an ``ipm reconstruct`` output (mesh.ply, params.json) and ``VIEWS_JSON`` the
``transforms.json`` it was fitted to (its first frame is the input view).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

SHOWN = 8
"""Parameters listed per run: the discrete ones first, then the continuous ones, in the generator's
order; the rest are counted."""


def parameter_lines(params: dict, generator: str) -> list[str]:
    """The text beside a run: its first ``SHOWN`` parameters (discrete first) and the pose."""
    from ipm.generators import get_generator

    spec = get_generator(generator).spec
    values = params["params"]
    names = [n for n, d in zip(spec.names, spec.discrete) if d] + [n for n, d in zip(spec.names, spec.discrete) if not d]
    discrete = dict(zip(spec.names, spec.discrete))
    lines = [f"{generator}: {len(spec)} parameters"]
    lines += [f"  {n} = {int(round(values[n]))}" if discrete[n] else f"  {n} = {values[n]:.3f}" for n in names[:SHOWN]]
    if len(names) > SHOWN:
        lines.append(f"  ... {len(names) - SHOWN} more")
    pose = params["pose"]
    lines.append(f"pose: yaw {np.degrees(pose['yaw']):.1f} deg, scale {pose['scale']:.3f}")
    return lines


def run_strip(run: Path, views_json: Path, tmp: Path) -> np.ndarray:
    """Input view | parts over it | turned 120 | turned 240, as an sRGB uint8 array."""
    from PIL import Image

    from ipm.io import load_views
    from ipm.render.preview import photo_sheet

    views = load_views(views_json, masks=False)
    frame = json.loads(views_json.read_text())["frames"][0]["file_path"]
    photo = views_json.parent / (frame if Path(frame).suffix else frame + ".png")
    camera = {"transform_matrix": views.c2w[0].tolist(), "fov_x_deg": float(np.degrees(views.fov_x))}
    out = tmp / f"{run.name}.png"
    photo_sheet(str(photo), str(run / "mesh.ply"), camera, str(out), height=256, spp=32)
    return np.asarray(Image.open(out).convert("RGB"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", nargs=2, action="append", required=True, metavar=("OUT_DIR", "VIEWS_JSON"))
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ipm.io import atomic_path
    from ipm.runtime import set_mitsuba_variant

    set_mitsuba_variant("cpu")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for run, views_json in args.run:
            run, views_json = Path(run), Path(views_json)
            for need in (run / "mesh.ply", run / "params.json", views_json):
                if not need.is_file():
                    print(f"overview_figure: {need} does not exist", file=sys.stderr)
                    return 2
            params = json.loads((run / "params.json").read_text())
            rows.append((run_strip(run, views_json, Path(tmp)), parameter_lines(params, params["generator"])))

    fig, axes = plt.subplots(len(rows), 2, figsize=(13.5, 2.75 * len(rows)), squeeze=False,
                             gridspec_kw={"width_ratios": [10.2, 3.3]})
    titles = ("input view", "fitted parts over it", "turned 120 deg", "turned 240 deg")
    for (strip, lines), (ax_img, ax_txt) in zip(rows, axes):
        ax_img.imshow(strip)
        ax_img.set_axis_off()
        for k, title in enumerate(titles):
            ax_img.text((k + 0.5) * strip.shape[1] / 4, -6, title, ha="center", va="bottom", fontsize=10)
        ax_txt.set_axis_off()
        ax_txt.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", family="monospace", fontsize=8.5,
                    transform=ax_txt.transAxes)
    fig.tight_layout(pad=1.0, h_pad=0.8, w_pad=0.4)
    with atomic_path(args.out) as tmp_png:
        fig.savefig(tmp_png, dpi=80, format="png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
