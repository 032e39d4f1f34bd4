"""Table 1 from metrics files: spread over seeds, class aggregates per split and family, failures."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from ipm.methods import row_label
from ipm.table import build_table

SPLIT = {"cup_1": "dev", "cup_ext": "dev", "cup_t1": "test", "cup_t2": "test", "cup_goblet": "test"}


def _run(root, row, label, kind, case, seed, iou, note="", **extra):
    folder = root / "evaluate" / row / case / f"s{seed}"
    folder.mkdir(parents=True)
    metrics = {"failed": note} if iou is None else {"iou_mean": iou, "shape_iou": min(1.0, iou + 0.01), "viou": 0.5,
                                                    **extra}
    (folder / "metrics.json").write_text(json.dumps(metrics))
    (folder / "row.json").write_text(json.dumps({"label": label, "kind": kind, "split": SPLIT[case],
                                                 "generator": "dishes", "seed": seed, "seconds": 1.0,
                                                 "note": f"failed: {note}" if iou is None else ""}))
    return str(folder / "metrics.json")


@pytest.fixture
def tables(tmp_path):
    ious = {("ours", "cup_t1"): [0.9, 0.8], ("ours", "cup_t2"): [0.95, 0.97], ("ours", "cup_goblet"): [0.7, 0.9],
            ("ours", "cup_1"): [0.99, 0.98]}
    files = [_run(tmp_path, "ours_1v", "ours", "method", case, seed, iou)
             for (_, case), values in ious.items() for seed, iou in enumerate(values)]
    files += [_run(tmp_path, "vh_2v", "hull", "baseline", case, 0, 0.6) for case in ("cup_t1", "cup_t2", "cup_goblet")]
    files += [_run(tmp_path, "vh_2v", "hull", "baseline", "cup_1", 0, None, "no points"),
              _run(tmp_path, "vh_2v", "hull", "baseline", "cup_ext", 0, 0.5)]
    out = {k: str(tmp_path / f"{k}.csv") for k in ("long", "wide", "summary")}
    build_table(files, out["long"], out["wide"], out["summary"], str(tmp_path / "table1.md"),
                cases=["cup_ext", "cup_1", "cup_t1", "cup_t2", "cup_goblet", "cup_99"])
    return (pd.read_csv(out["long"]), pd.read_csv(out["summary"]), pd.read_csv(out["wide"], index_col=0),
            (tmp_path / "table1.md").read_text())


def test_per_case_lines_give_mean_std_and_worst_over_seeds(tables):
    long, summary, _, _ = tables
    assert len(long) == 13 and set(long["family"]) == {"in", "out"}
    line = summary[(summary["label"] == "ours") & (summary["case"] == "cup_t1")].iloc[0]
    assert line["n_seeds"] == 2 and line["iou_mean"] == pytest.approx(0.85, abs=1e-4)
    assert line["iou_mean_std"] == pytest.approx(np.std([0.9, 0.8], ddof=1), abs=1e-4) and line["iou_mean_worst"] == pytest.approx(0.8, abs=1e-4)
    one = summary[(summary["label"] == "hull") & (summary["case"] == "cup_t1")].iloc[0]
    assert one["n_seeds"] == 1 and np.isnan(one["iou_mean_std"])  # one seed: no spread to report


def test_aggregates_are_means_over_the_cases_of_a_class_split_and_family(tables):
    _, summary, wide, md = tables
    # the cases in the configured order (one configured but never run left out), aggregates after
    assert list(wide.columns)[:5] == ["cup_ext", "cup_1", "cup_t1", "cup_t2", "cup_goblet"]
    assert all("/" in c for c in list(wide.columns)[5:])
    agg = summary[summary["label"] == "ours"].set_index("case")
    assert agg.loc["cups/test/in", "iou_mean"] == pytest.approx((0.85 + 0.96) / 2, abs=1e-4)
    assert agg.loc["cups/test/out", "iou_mean"] == pytest.approx(0.8, abs=1e-4)
    assert agg.loc["cups/test/all", "iou_mean"] == pytest.approx((0.85 + 0.96 + 0.8) / 3, abs=1e-4)
    assert agg.loc["cups/test/all", "iou_mean_worst"] == pytest.approx(0.8, abs=1e-4)  # the worst case
    per_seed = [np.mean([0.9, 0.95, 0.7]), np.mean([0.8, 0.97, 0.9])]  # mean over cases, per seed
    assert agg.loc["cups/test/all", "iou_mean_std"] == pytest.approx(np.std(per_seed, ddof=1), abs=1e-4)
    assert "cups/dev/in" in agg.index and "cups/dev/all" not in agg.index  # ours skipped cup_ext: no average
    hull = summary[summary["label"] == "hull"].set_index("case")
    assert hull.loc["cup_1", "n_failed"] == 1 and np.isnan(hull.loc["cup_1", "iou_mean"])
    assert "cups/dev/all" not in hull.index or np.isnan(hull.loc["cups/dev/all", "iou_mean"])
    assert wide.loc["ours", "cups/test/all"] == pytest.approx(0.87, abs=1e-3)
    assert md.index("cups, test split") < md.index("cups, dev split")
    assert "0.850 ± 0.071 (worst 0.800)" in md


def test_a_withheld_cameras_errors_reach_the_table(tmp_path):
    """The photo row's params.json records its camera's errors (``ipm.photo.camera_errors``); the
    evaluation turns them into absolute pitch and field-of-view errors, which the table averages
    over seeds; other rows leave them empty."""
    from ipm.metrics.recovery import camera_recovery
    from ipm.photo import c2w, camera_errors

    given = c2w(np.radians(22.0))
    errors = [camera_errors({"pitch_deg": pitch, "roll_deg": 0.0, "fov_x_deg": fov}, given, np.radians(40.0))
              for pitch, fov in ((18.0, 50.0), (23.0, 38.0))]
    cams = [camera_recovery({"camera_error": e}) for e in errors]
    assert cams[0] == pytest.approx({"camera_pitch_err_deg": 4.0, "camera_fov_err_pct": 25.0}, abs=1e-6)
    assert cams[1] == pytest.approx({"camera_pitch_err_deg": 1.0, "camera_fov_err_pct": 5.0}, abs=1e-6)
    assert camera_recovery({"params": {}}) == {} and camera_recovery(None) == {}
    files = []
    for seed, cam in enumerate(cams):
        files.append(_run(tmp_path, "photo_1v", "photo", "method", "cup_1", seed, 0.5))
        metrics = json.loads(open(files[-1]).read())
        open(files[-1], "w").write(json.dumps({**metrics, **cam}))
    files.append(_run(tmp_path, "ours_1v", "ours", "method", "cup_1", 0, 0.9))
    out = {k: str(tmp_path / f"{k}.csv") for k in ("long", "wide", "summary")}
    build_table(files, out["long"], out["wide"], out["summary"], str(tmp_path / "table1.md"))
    summary = pd.read_csv(out["summary"]).set_index(["label", "case"])
    assert summary.loc[("photo", "cup_1"), "camera_pitch_err_deg"] == pytest.approx(2.5)
    assert summary.loc[("photo", "cup_1"), "camera_fov_err_pct"] == pytest.approx(15.0)
    assert np.isnan(summary.loc[("ours", "cup_1"), "camera_pitch_err_deg"])


def _photo_and_diff(root, rows=("photo_1v", "diff_1v")):
    """Runs of a camera-withheld row (world IoU low, shape IoU high, camera errors) and of the diff
    row on two test cases, two seeds; the table built from those of ``rows``; the runs' values."""
    runs = {"photo_1v": {"cup_t1": [(0.62, 0.91, 2.0, 10.0), (0.58, 0.93, 4.0, 20.0)],
                         "cup_goblet": [(0.70, 0.96, 1.0, 5.0), (0.66, 0.90, 3.0, 15.0)]},
            "diff_1v": {"cup_t1": [(0.80, 0.85, None, None), (0.84, 0.86, None, None)],
                        "cup_goblet": [(0.90, 0.92, None, None), (0.88, 0.90, None, None)]}}
    files = []
    for row in rows:
        for case, seeds in runs[row].items():
            for seed, (world, shape, pitch, fov) in enumerate(seeds):
                camera = {} if pitch is None else {"camera_pitch_err_deg": pitch, "camera_fov_err_pct": fov}
                files.append(_run(root, row, row_label(row.split("_1v")[0], 1), "method", case, seed, world,
                                  shape_iou=shape, **camera))
    out = {k: str(root / f"{k}.csv") for k in ("long", "wide", "summary")}
    build_table(files, out["long"], out["wide"], out["summary"], str(root / "table1.md"))
    return pd.read_csv(out["summary"]), (root / "table1.md").read_text(), runs


def _md_cells(md: str, label: str) -> list[str]:
    """The cells of ``label``'s line in the first (test split, world IoU) block of ``md``."""
    line = next(line for line in md.splitlines() if line.startswith(f"| {label} |"))
    return [c.strip() for c in line.strip("|").split("|")][1:]


def test_a_camera_withheld_row_leads_with_its_shape_iou_the_world_iou_and_camera_errors_beside_it(tmp_path):
    """photo and photo_fov are scored by the shape IoU (``Method.scored_by``): its mean ± std
    (worst seed) leads the cell, named, then the world IoU and the camera's errors; the class
    aggregates spread the shape IoU too; a note under the table says why; the diff row is as without it."""
    from ipm.table import SHAPE_NOTE, scored_by

    assert scored_by("photo_1v") == scored_by("photo_fov_1v") == scored_by("photo_1v_fovgrid") == "shape_iou"
    assert scored_by("diff_1v") == scored_by("line_convex_hull") == "iou_mean"
    summary, md, runs = _photo_and_diff(tmp_path / "both")
    photo, diff = row_label("photo", 1), row_label("diff", 1)
    cells = _md_cells(md, photo)
    for cell, case in zip(cells, ("cup_t1", "cup_goblet")):
        world, shape, pitch, fov = (np.array(v) for v in zip(*runs["photo_1v"][case]))
        assert cell == (f"shape {shape.mean():.3f} ± {shape.std(ddof=1):.3f} (worst {shape.min():.3f}) · "
                        f"world {world.mean():.3f} · pitch error {pitch.mean():.1f}° · FOV error {fov.mean():.1f}%")
    values = np.array([runs["photo_1v"][c] for c in ("cup_t1", "cup_goblet")])  # case x seed x (world, shape, ...)
    shape_by_case, shape_by_seed = values[..., 1].mean(axis=1), values[..., 1].mean(axis=0)
    assert cells[-1].startswith(f"shape {shape_by_case.mean():.3f} ± {shape_by_seed.std(ddof=1):.3f} "
                                f"(worst {shape_by_case.min():.3f}) · world {values[..., 0].mean():.3f} · ")
    agg = summary.set_index(["label", "case"]).loc[(photo, "cups/test/all")]
    assert agg["shape_iou_std"] == pytest.approx(shape_by_seed.std(ddof=1), abs=1e-6)
    assert SHAPE_NOTE.format(rows=photo) in md.split("(shape_iou)")[0]  # under the world-IoU tables only
    assert all("shape" not in c and "world" not in c for c in _md_cells(md.split("(shape_iou)")[1], photo))
    alone, alone_md, _ = _photo_and_diff(tmp_path / "alone", rows=("diff_1v",))
    assert _md_cells(md, diff) == _md_cells(alone_md, diff) and not any("shape" in c for c in _md_cells(md, diff))
    world = np.array(runs["diff_1v"]["cup_t1"])[:, 0]
    assert _md_cells(md, diff)[0] == f"{world.mean():.3f} ± {world.std(ddof=1):.3f} (worst {world.min():.3f})"
    assert "scored by the shape IoU" not in alone_md


@pytest.mark.parametrize("entry, row", [
    ({"name": "visual_hull", "views": 12}, "visual_hull_12v"),
    ({"name": "ga", "views": 1, "tag": "labels"}, "ga_1v_labels"),
    ({"name": "diff", "views": 1, "mask": "edge +2 px"}, "diff_1v_maskedgep2px"),
    ({"name": "diff", "views": 1, "tag": "presets", "mask": "hole"}, "diff_1v_presets_maskhole"),
])
def test_a_row_id_is_taken_apart_as_it_was_made(entry, row):
    """``ipm.table``: the row id a methods entry gets, the workflow's constraint on it, its parts and
    its untagged twin are one grammar."""
    import re

    from ipm.table import ROW_ID, row_id, row_parts, untagged

    assert row_id(entry) == row and re.fullmatch(ROW_ID, row)
    parts = row_parts(row)
    assert (parts["name"], parts["views"], parts["tag"]) == (entry["name"], entry["views"], entry.get("tag"))
    assert (parts["mask"] is None) == ("mask" not in entry)
    assert untagged(row) == (row_id({k: v for k, v in entry.items() if k != "tag"}) if "tag" in entry else None)


def test_reference_lines_and_malformed_ids_are_no_methods_rows():
    import re

    from ipm.table import ROW_ID, row_parts, untagged

    for row in ("line_convex_hull", "diff", "diff_1v_maskx_masky", "diff_v1"):
        assert row_parts(row) is None and untagged(row) is None and not re.fullmatch(ROW_ID, row)
