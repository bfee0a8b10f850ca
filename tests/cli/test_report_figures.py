"""Figures that would look wrong without a word of why: a KITTI drift missing for a path under
100 m, classes a method never outputs (not scores of 0), the first progress line's ETA (the first
frame pays the start-up), and noise-labelled points that reach ICP on purpose."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
from rich.console import Console

from prc_slam import labels as L
from prc_slam.evaluation.metrics import ConfusionAccumulator

NOT_OUTPUT = "not output by this method"


def rendered(table) -> str:
    console = Console(width=200, record=True, file=io.StringIO())
    console.print(table)
    return console.export_text()


def a_run(path_m: float, kitti: float | None) -> tuple[SimpleNamespace, dict]:
    """What :func:`prc_slam.jobs.report.markdown_report` reads of a compare run: two variants."""
    variant = {
        "ate_rmse_m": 0.05, "rpe_trans_m": 0.02, "kitti_trans_pct": kitti, "kitti_rot_deg_per_m": None,
        "path_length_m": path_m, "ms_per_frame": 20.0, "points_in": 1000, "points_to_icp": 300, "frames": 5,
        "points_in_per_class": {"ground": 600, "building": 300, "noise": 100},
        "points_kept_per_class": {"ground": 60, "building": 200, "noise": 37},
    }  # fmt: skip
    metrics = {"variants": {"raw": dict(variant, points_to_icp=1000), "prc": variant}}
    result = SimpleNamespace(times=np.arange(5) * 0.1, names=[f"{i:06d}" for i in range(5)], gt_poses=np.eye(4)[None])
    return result, metrics


@pytest.mark.parametrize("path_m", [0.0, 23.4, 99.9])
def test_a_missing_kitti_drift_says_the_path_is_too_short(path_m):
    from prc_slam.cli.common import variant_table
    from prc_slam.jobs.report import markdown_report

    result, metrics = a_run(path_m, None)
    report = markdown_report(result, metrics, "t")
    table = report.split("\n\n")[1]
    assert table.count("- (path < 100 m)") == 2, table
    assert f"the path is {path_m:.1f} m long" in report and "100 to 800 m" in report
    assert rendered(variant_table(metrics, "t")).count("- (path < 100 m)") == 2


def test_a_kitti_drift_on_a_long_path_shows_with_no_note():
    from prc_slam.cli.common import variant_table
    from prc_slam.jobs.report import markdown_report

    result, metrics = a_run(250.0, 1.234)
    report = markdown_report(result, metrics, "t")
    assert "1.234" in report and "path <" not in report and "m long" not in report
    assert "1.234" in rendered(variant_table(metrics, "t"))


def scores_of_a_method() -> dict:
    """A method that outputs ground (right), building (always wrong: the reference is ground)
    and never vehicle, although the reference has vehicles."""
    ref = np.array([L.GROUND] * 50 + [L.VEHICLE] * 30 + [L.GROUND] * 20, np.uint8)
    pred = np.array([L.GROUND] * 50 + [L.GROUND] * 30 + [L.BUILDING] * 20, np.uint8)
    acc = ConfusionAccumulator()
    acc.add(ref, pred)
    return {"per_class": acc.per_class([L.GROUND, L.BUILDING, L.VEHICLE])}


def table_rows(text: str) -> dict[str, str]:
    """Table lines by class name (console tables and markdown)."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.replace("│", "|").split("|") if c.strip()]
        if cells:
            rows[cells[0].split(" (")[0]] = line
    return rows


def test_a_class_never_output_is_said_so_and_a_wrong_one_keeps_its_zero():
    from prc_slam.cli.common import class_table
    from prc_slam.jobs.report import classification_section, mapclass_section

    metrics = scores_of_a_method()
    mc = {"points": 100, "poses": "prc", "seconds": 1.0, "points_per_s": 100.0, "counts": {}, **metrics}
    for text in (
        rendered(class_table(metrics, "t")),
        classification_section(metrics, "t"),
        mapclass_section(mc),
    ):
        rows = table_rows(text)
        assert NOT_OUTPUT in rows["vehicle"] and "0.000" not in rows["vehicle"] and "| 0 |" not in rows["vehicle"]
        assert NOT_OUTPUT not in rows["building"]
        assert "0.000" in rows["building"] or "| 0 |" in rows["building"], rows["building"]  # output, all wrong
        assert NOT_OUTPUT not in rows["ground"]


def test_a_class_the_reference_never_has_is_said_so():
    """A detector's curbs scored against a reference without curbs (SemanticKITTI): its precision
    is 0 by construction, and the row says why instead of a bare 0.000."""
    from prc_slam.cli.common import class_table
    from prc_slam.jobs.report import NOT_IN_REFERENCE, classification_section

    ref = np.array([L.GROUND] * 80 + [L.BUILDING] * 20, np.uint8)
    pred = np.array([L.GROUND] * 80 + [L.CURB] * 5 + [L.BUILDING] * 15, np.uint8)
    acc = ConfusionAccumulator()
    acc.add(ref, pred)
    metrics = {"per_class": acc.per_class([L.GROUND, L.BUILDING, L.CURB])}
    for text in (rendered(class_table(metrics, "t")), classification_section(metrics, "t")):
        rows = table_rows(text)
        assert NOT_IN_REFERENCE in rows["curb"], rows["curb"]
        assert NOT_IN_REFERENCE not in rows["building"] and NOT_IN_REFERENCE not in rows["ground"]


def test_the_first_frame_gives_no_eta_and_the_next_ones_leave_it_out(monkeypatch):
    """The first frame takes 60 s (numba compiling), the others 0.5 s: no ETA on the first
    line; from the second on the ETA is the remaining frames at 0.5 s (49 s for 98), not at the
    first frame's pace (5940 s)."""
    from prc_slam.jobs import progress as P

    clock = [0.0]
    monkeypatch.setattr(P.time, "monotonic", lambda: clock[0])
    task = P.Task("odometry", 100, None, every_s=1e9)
    clock[0] = 60.0
    task.advance()
    first = task.line(clock[0])
    assert "ETA" not in first.replace("ETA from the next", "") and "1/100" in first
    clock[0] = 60.5
    task.advance()
    line = task.line(clock[0])
    eta = float(line.split("ETA ")[1].split(" s")[0])
    assert eta == pytest.approx(98 * 0.5, abs=1) and "2.00/s" in line
    for _ in range(98):
        clock[0] += 0.5
        task.advance()
    assert "ETA" not in task.line(clock[0]) and "100/100" in task.line(clock[0])


def test_the_report_says_how_much_of_each_class_reached_icp_and_why_noise_does():
    from prc_slam.jobs.report import markdown_report

    result, metrics = a_run(250.0, 1.0)
    report = markdown_report(result, metrics, "t")
    section = report.split("## Points per class, `prc`")[1].split("\n## ")[0]
    assert "| class | in | to ICP | share to ICP |" in section
    assert "| noise | 100 | 37 | 37% |" in section and "| ground | 600 | 60 | 10% |" in section
    why = section.split("| building")[1]
    assert "37 of the 100 noise-labelled points" in why and "one-sided" in why and "keep_one_sided" in why
    metrics["variants"]["prc"]["points_kept_per_class"]["noise"] = 0  # all noise dropped: nothing to explain
    assert "one-sided" not in markdown_report(result, metrics, "t")
