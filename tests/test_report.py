"""The HTML report on a tiny results tree: Table 1 laid out as the paper's, best marks, failures
with their reasons, provenance, 3D views; and the same page opened in headless Chromium."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh
from markupsafe import escape
from PIL import Image

from ipm.io import save_glb, save_ply
from ipm.methods import row_label
from ipm.table import build_table
from reports import build
from reports.browser import check_report

SPLIT = {"cup_1": "dev", "cup_t1": "test", "cup_goblet": "test"}
OURS, HULL, LINE = "ours (diff, 1 view)", "visual hull (6 views)", "convex hull (reference)"
RUNS = [  # row, label, kind, case, seed, IoU (None: failed)
    ("diff_1v", OURS, "method", "cup_t1", 0, 0.95), ("diff_1v", OURS, "method", "cup_t1", 1, 0.90),
    ("diff_1v", OURS, "method", "cup_goblet", 0, 0.95), ("diff_1v", OURS, "method", "cup_1", 0, 0.97),
    ("visual_hull_6v", HULL, "baseline", "cup_t1", 0, 0.88), ("visual_hull_6v", HULL, "baseline", "cup_1", 0, 0.93),
    ("visual_hull_6v", HULL, "baseline", "cup_goblet", 0, None),
    ("line_convex_hull", LINE, "reference", "cup_t1", 0, 0.99),
    ("line_convex_hull", LINE, "reference", "cup_1", 0, 0.99),
    ("line_convex_hull", LINE, "reference", "cup_goblet", 0, 0.98),
]
FAILURE = "no points survived carving"


def _png(path: Path, colour, size=(24, 16)) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", size, colour).save(path)


def _run(root: Path, row, label, kind, case, seed, iou, **extra) -> str:
    """metrics.json (``extra`` over the defaults), row.json and the pictures of one run; its mesh
    (GLB for ours, PLY otherwise), trace and benchmark file."""
    folder = root / "results/evaluate" / row / case / f"s{seed}"
    recon = root / "results/reconstruct" / row / case / f"s{seed}"
    recon.mkdir(parents=True)
    metrics = {"failed": FAILURE} if iou is None else {
        "iou_mean": iou, "shape_iou": iou, "viou": iou - 0.2, "chamfer_l1": 0.05 / iou, "chamfer_l2": 0.004 / iou,
        "n_triangles": 320, "malformed_share": 0.01, "recon_watertight": kind != "baseline", **extra}
    _png(folder / "gallery.png", (90, 120, 200), (72, 48))
    _png(folder / "preview.png", (200, 200, 200))
    (folder / "metrics.json").write_text(json.dumps(metrics))
    (folder / "row.json").write_text(json.dumps({
        "label": label, "kind": kind, "split": SPLIT[case], "generator": "dishes", "seed": seed, "seconds": 2.0 + seed,
        "machine": "host-1 · Test CPU · 2 CPUs · Linux" if kind != "reference" else "not recorded",
        "note": f"failed: {FAILURE}" if iou is None else ""}))
    if iou is not None:
        sphere = trimesh.creation.icosphere(subdivisions=2)
        save_ply(recon / "mesh.ply", sphere.vertices, sphere.faces)
        if kind == "method":
            save_glb(recon / "mesh.glb", sphere.vertices, sphere.faces, np.zeros(len(sphere.faces), int), ("body",))
            pd.DataFrame({"stage": "memetic", "res": 64, "eval": range(6), "origin": "mug",
                          "loss": [0.3, 0.2, 0.25, 0.1, 0.12, 0.05], "best": [0.3, 0.2, 0.2, 0.1, 0.1, 0.05],
                          "seconds": np.linspace(0.5, 3.0, 6)}).to_csv(recon / "trace.csv", index=False)
    if kind != "reference":
        bench = root / "logs/benchmark/reconstruct" / row / case / f"s{seed}.tsv"
        bench.parent.mkdir(parents=True, exist_ok=True)
        bench.write_text("s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
                         f"{3.5 + seed}\t0:00:03\t{500 + 10 * seed}\t900\t400\t450\t0.1\t0.2\t80\t3.1\n")
    return str(folder / "metrics.json")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A results tree (three rows, three cases, one failed run) and its report."""
    root = tmp_path_factory.mktemp("report")
    files = [_run(root, *r) for r in RUNS]
    res = root / "results"
    out = {k: str(res / f"{k}.csv") for k in ("table", "table_iou", "table_summary")}
    build_table(files, out["table"], out["table_iou"], out["table_summary"])
    for case in SPLIT:
        _png(res / "synth" / case / "hemi1" / "rgb" / "000.png", (30, 140, 60))
        _png(res / "synth" / case / "hemi1" / "masks" / "000.png", (255, 255, 255))
        _png(res / "synth" / case / "gallery.png", (150, 150, 150), (72, 48))
    config = {"profile": "tiny", "seeds": [0, 1], "cases": list(SPLIT), "evaluate": {"views": 64}}
    html = res / "report" / "index.html"
    build.build_report(table_csv=out["table"], wide_csv=out["table_iou"], summary_csv=out["table_summary"],
                       metrics=files, out_html=str(html), config=config,
                       input_dirs={c: str(res / "synth" / c / "hemi1") for c in SPLIT},
                       benchmarks=sorted(map(str, (root / "logs").rglob("*.tsv"))))
    summary = pd.read_csv(out["table_summary"])
    return {"root": root, "html": html, "text": html.read_text(), "table": pd.read_csv(out["table"]),
            "summary": summary}


def _cells(blocks: list[dict]) -> dict:
    """(label, column) -> cell of every block."""
    return {(r["label"], c["name"]): cell
            for b in blocks for r in b["rows"] for c, cell in zip(b["columns"], r["cells"])}


@pytest.mark.slow
def test_table1_rows_are_methods_columns_cases_then_aggregates_test_split_first(report):
    text = report["text"]
    assert text.index("Table 1: 64-view silhouette IoU, test split") < text.index("Dev split")
    [test] = build.metric_blocks(report["summary"], report["table"], build.TABLE1, "test")
    assert [c["name"] for c in test["columns"]] == ["cup_t1", "cup_goblet", "cups/test/in", "cups/test/out",
                                                     "cups/test/all"]
    assert [r["label"] for r in test["rows"]] == [HULL, OURS, LINE]  # baselines, ours, reference lines
    cell = _cells([test])[(OURS, "cup_t1")]
    assert cell["main"] == "0.925" and cell["rest"] == "± 0.035 (worst 0.900)"


def test_best_is_marked_per_column_and_reference_lines_never_win(report):
    cells = _cells(build.metric_blocks(report["summary"], report["table"], build.TABLE1, "test"))
    assert "best" in cells[(OURS, "cup_t1")]["cls"] and "best" not in cells[(HULL, "cup_t1")]["cls"]
    assert not any("best" in cells[(LINE, c)]["cls"] for c in ("cup_t1", "cup_goblet"))  # 0.99 > 0.85: context
    chamfer = _cells(build.metric_blocks(report["summary"], report["table"], build.SIBLINGS[2], "test"))
    assert build.SIBLINGS[2].metric == "chamfer_l1"  # smaller is better: ours has the smaller one here
    assert "best" in chamfer[(OURS, "cup_t1")]["cls"] and "best" not in chamfer[(HULL, "cup_t1")]["cls"]


def test_failures_show_a_dash_with_the_reason_on_hover(report):
    cells = _cells(build.metric_blocks(report["summary"], report["table"], build.TABLE1, "test"))
    failed = cells[(HULL, "cup_goblet")]
    assert failed["main"] == "-" and "failed" in failed["cls"] and FAILURE in failed["title"]
    assert FAILURE in cells[(HULL, "cups/test/all")]["title"]  # the aggregate over it says why too
    title = f"cup_goblet seed 0: failed: {FAILURE}"
    assert re.search(f'<td data-v="" class="failed[^"]*" title="{title}">-', report["text"])  # what the reader hovers


def test_volumetric_iou_of_a_mesh_that_is_not_watertight_is_marked_unreliable(report):
    viou = build.SIBLINGS[1]
    assert viou.metric == "viou"
    cells = _cells(build.metric_blocks(report["summary"], report["table"], viou, "test"))
    assert "caveat" in cells[(HULL, "cup_t1")]["cls"] and "not watertight" in cells[(HULL, "cup_t1")]["title"]
    assert "caveat" not in cells[(OURS, "cup_t1")]["cls"]


def test_page_is_self_contained_with_everything_a_reader_needs(report):
    text = report["text"]
    for needle in ("Table 1", OURS, "data:image/png;base64", "test split", "Parameter recovery", "The paper's Table 1",
                   "0.967", "Volumetric IoU", "Chamfer-L1", "Chamfer-L2", "Parameter error", "Time and peak memory",
                   "host-1 · Test CPU · 2 CPUs · Linux", "not recorded", "numpy", "profile: tiny", "<model-viewer",
                   'data-glb-gz="', "convergence of seed 0", "Dev split", 'table class="metric sortable table1"'):
        assert needle in text, needle
    assert text.count('<script type="module">') == 1  # model-viewer inlined once
    assert not re.search(r'(src|href)="(https?:)?//', text)  # nothing fetched from the network
    timing = text[text.index('id="timing"'):text.index('id="cases"')]
    ours = timing[timing.index(f"<td>{OURS}</td>"):]
    assert ours[:ours.index("</tr>")].endswith("<td>510</td>")  # peak RSS of ours' two jobs (500 and 510 MB)


@pytest.mark.slow
def test_a_camera_withheld_row_leads_with_its_shape_iou_and_wins_by_it(report, tmp_path):
    """Table 1 on the page: the photo row's cell is "shape <mean>" (its value, sorted and compared
    for the best mark), the world IoU and the camera's errors beside it, a note under the table;
    the diff row's cells are as on a page without it; the shape-IoU table stays plain."""
    photo = row_label("photo", 1)
    values = {"cup_t1": [(0.60, 0.96, 2.0, 10.0), (0.56, 0.94, 4.0, 30.0)], "cup_goblet": [(0.70, 0.90, 1.0, 5.0)]}
    runs = [r for r in RUNS if r[0] == "diff_1v"]
    files = [_run(tmp_path, *r) for r in runs]
    files += [_run(tmp_path, "photo_1v", photo, "method", case, seed, world, shape_iou=shape,
                   camera_pitch_err_deg=pitch, camera_fov_err_pct=fov)
              for case, seeds in values.items() for seed, (world, shape, pitch, fov) in enumerate(seeds)]
    res = tmp_path / "results"
    out = {k: str(res / f"{k}.csv") for k in ("table", "table_iou", "table_summary")}
    build_table(files, out["table"], out["table_iou"], out["table_summary"])
    html = res / "report" / "index.html"
    build.build_report(table_csv=out["table"], wide_csv=out["table_iou"], summary_csv=out["table_summary"],
                       metrics=files, out_html=str(html), config={"cases": ["cup_t1", "cup_goblet"]})
    summary, table, text = pd.read_csv(out["table_summary"]), pd.read_csv(out["table"]), html.read_text()
    [block] = build.metric_blocks(summary, table, build.TABLE1, "test")
    cells = _cells([block])
    world, shape, pitch, fov = (np.array(v) for v in zip(*values["cup_t1"]))
    cell = cells[(photo, "cup_t1")]
    assert cell["main"] == f"shape {shape.mean():.3f}" and float(cell["v"]) == pytest.approx(shape.mean())
    assert cell["rest"] == (f"± {shape.std(ddof=1):.3f} (worst {shape.min():.3f}) · world {world.mean():.3f} · "
                            f"pitch error {pitch.mean():.1f}° · FOV error {fov.mean():.1f}%")
    diff_world = np.mean([r[5] for r in runs if r[3] == "cup_t1"])
    assert shape.mean() > diff_world > world.mean()  # the fixture: the headline wins where the world IoU would not
    assert "best" in cell["cls"] and "best" not in cells[(OURS, "cup_t1")]["cls"]
    before = _cells(build.metric_blocks(report["summary"], report["table"], build.TABLE1, "test"))
    for column in ("cup_t1", "cup_goblet", "cups/test/all"):
        assert {k: cells[(OURS, column)][k] for k in ("main", "rest", "v")} == \
            {k: before[(OURS, column)][k] for k in ("main", "rest", "v")}
    assert photo in block["note"] and OURS not in block["note"] and f"<p class=\"note\">{escape(block['note'])}" in text
    assert f"{cell['main']}<span class=\"rest\">" in text and "shape IoU per seed" in text
    legend = [t.get_text() for t in build._aggregate_bars(summary).axes[0].get_legend().get_texts()]
    assert f"{photo}, shape IoU" in legend and OURS in legend  # the bars of the aggregates lead with it too
    shape_table = _cells(build.metric_blocks(summary, table, build.SIBLINGS[0], "test"))
    assert build.SIBLINGS[0].metric == "shape_iou" and shape_table[(photo, "cup_t1")]["main"] == f"{shape.mean():.3f}"


@pytest.mark.slow
def test_mask_rows_are_shown_against_their_true_mask_twins(report, tmp_path):
    """Rows that read degraded masks get a section of their own: per class and degradation the IoU
    lost against the same row on the true masks, paired by case and seed, and a plot of IoU against
    the edge's shift; a run without mask rows has no such section."""
    from reports.masks import mask_pairs, mask_plot, mask_table

    assert "Mask errors" not in report["text"]
    runs = [r for r in RUNS if r[0] == "diff_1v"]
    degraded = {"edge +2 px": 0.03, "edge -2 px": 0.05, "hole": 0.0}  # IoU lost on every run
    files = [_run(tmp_path, *r) for r in runs]
    for name, loss in degraded.items():
        row = f"diff_1v_mask{name.replace(' ', '').replace('+', 'p').replace('-', 'm')}"
        for r in runs:
            files.append(_run(tmp_path, row, f"{OURS} [mask: {name}]", "method", r[3], r[4], r[5] - loss))
            info = Path(files[-1]).parent / "row.json"
            info.write_text(json.dumps({**json.loads(info.read_text()), "mask": name}))
    res = tmp_path / "results"
    out = {k: str(res / f"{k}.csv") for k in ("table", "table_iou", "table_summary")}
    build_table(files, out["table"], out["table_iou"], out["table_summary"])
    table = pd.read_csv(out["table"])
    pairs = mask_pairs(table)
    assert len(pairs) == len(runs) * len(degraded) and set(pairs["label"]) == {OURS}
    for name, loss in degraded.items():
        part = pairs[pairs["mask"] == name]
        np.testing.assert_allclose(part["shape_iou_loss"], loss, atol=1e-9)
        np.testing.assert_allclose(part["iou_mean_loss"], loss, atol=1e-9)
    summary = mask_table(pairs).set_index("degradation")
    assert summary.loc["edge -2 px", "runs"] == len(runs)
    assert summary.loc["edge -2 px", "shape IoU lost (mean)"] == pytest.approx(0.05)
    fig = mask_plot(pairs)
    [line, _] = fig.axes[0].get_lines()
    assert list(line.get_xdata()) == [-2.0, 0.0, 2.0]  # the hole moves no edge: in the table, not the plot
    true = np.mean([r[5] for r in runs])
    np.testing.assert_allclose(line.get_ydata(), [true - 0.05, true, true - 0.03])
    html = res / "report" / "index.html"
    build.build_report(table_csv=out["table"], wide_csv=out["table_iou"], summary_csv=out["table_summary"],
                       metrics=files, out_html=str(html), config={"cases": list(SPLIT)})
    text = html.read_text()
    assert "Mask errors: what a wrong mask costs" in text and 'href="#masks"' in text
    assert f"{OURS} [mask: edge +2 px]" in text and "shape IoU lost (mean)" in text


@pytest.mark.slow
def test_pictures_missing_on_disk_say_so(report, tmp_path):
    res = tmp_path / "results"
    shutil.copytree(report["root"] / "results", res)
    (res / "evaluate/diff_1v/cup_t1/s0/gallery.png").unlink()
    build.build_report(table_csv=str(res / "table.csv"), wide_csv=str(res / "table_iou.csv"), metrics=[],
                       out_html=str(res / "index.html"), config={"cases": ["cup_t1"]})
    assert "(missing)" in (res / "index.html").read_text()


def test_large_models_are_left_out_with_a_note(report, monkeypatch):
    monkeypatch.setattr(build, "MAX_MODEL_BYTES", 1000)
    model = build._model(report["root"] / "results/reconstruct/diff_1v/cup_t1/s0", "x")
    assert model["gz"] is None and "the page embeds models up to" in model["note"]


def test_trace_plots_show_loss_against_evaluations_and_wall_time():
    diff = pd.DataFrame({"stage": ["memetic"] * 3 + ["refine"] * 2, "res": [64] * 3 + [128] * 2, "eval": range(5),
                         "loss": [0.3, 0.2, 0.1, 0.08, 0.05], "best": [0.3, 0.2, 0.1, 0.08, 0.05],
                         "seconds": [0.1, 0.2, 0.3, 0.5, 0.7]})
    ga = pd.DataFrame({"eval": range(4), "node": 0, "level": [0, 0, 1, 1], "generation": 0,
                       "loss": [0.9, 0.8, 0.85, 0.7], "best": [0.9, 0.8, 0.8, 0.7]})
    assert len(build._trace_plot(diff).axes) == 2 and len(build._trace_plot(ga).axes) == 1
    # with the input-view IoU at the stages' ends, a second row plots it against the same axes
    diff["iou"] = [np.nan, np.nan, 0.7, np.nan, 0.9]
    axes = build._trace_plot(diff).axes
    assert len(axes) == 4 and list(axes[2].lines[0].get_ydata()) == [0.7, 0.9]


@pytest.mark.slow
def test_check_report_in_chromium_passes_and_saves_screenshots(report, tmp_path):
    result = check_report(str(report["html"]), str(tmp_path / "shots"), [OURS, HULL, LINE])
    assert result["rows_missing"] == [] and result["errors"] == [] and result["images_broken"] == []
    assert result["models_loaded"] == 8 and result["models_failed"] == []  # every run shown that has a mesh
    assert result["images_ok"] > 10
    for name in ("page.png", "table1.png", "model.png"):
        assert Image.open(tmp_path / "shots" / name).size[0] > 100
    assert json.loads((tmp_path / "shots" / "check.json").read_text())["screenshots"] == result["screenshots"]


@pytest.mark.slow
def test_check_report_fails_with_one_clear_line_on_a_broken_page(report, tmp_path):
    text = report["text"]
    text = re.sub(r'src="data:image/png;base64,[^"]+"', 'src="data:image/png;base64,AAAA"', text, count=1)
    text = re.sub(r'data-glb-gz="[^"]+"', 'data-glb-gz="bm90IGEgZ2xi"', text, count=1)
    broken = tmp_path / "broken.html"
    broken.write_text(text)
    with pytest.raises(RuntimeError) as err:
        check_report(str(broken), str(tmp_path / "shots"), [OURS, "no such row"])
    message = str(err.value)
    assert "\n" not in message
    for part in ("Table 1 lacks row(s) no such row", "1 image(s) did not load", "1 3D view(s) did not load"):
        assert part in message, message
    assert json.loads((tmp_path / "shots" / "check.json").read_text())["rows_missing"] == ["no such row"]
