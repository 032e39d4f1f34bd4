"""Table 1 from metrics files: spread over seeds, class aggregates per split and family, failures."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from ipm.table import build_table

SPLIT = {"cup_1": "dev", "cup_ext": "dev", "cup_t1": "test", "cup_t2": "test", "cup_goblet": "test"}


def _run(root, row, label, kind, case, seed, iou, note=""):
    folder = root / "evaluate" / row / case / f"s{seed}"
    folder.mkdir(parents=True)
    metrics = {"failed": note} if iou is None else {"iou_mean": iou, "shape_iou": min(1.0, iou + 0.01), "viou": 0.5}
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
    build_table(files, out["long"], out["wide"], out["summary"], str(tmp_path / "table1.md"))
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
