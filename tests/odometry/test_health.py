"""A variant's health over a whole run: a variant whose frames are mostly
suspicious, or that disagrees with every other variant for most of the run, is not "ok"; when no
variant is ok, report.md, metrics.json and the console lead with one line saying so."""

from __future__ import annotations

import json
import logging
from types import SimpleNamespace

import numpy as np
import pytest

from data_tools.formats.trajectory_io import write_kitti_poses, write_tum_poses
from prc_slam.cli.compare import warn_failed
from prc_slam.config import Config
from prc_slam.jobs.report import write_compare_outputs
from prc_slam.odometry.compare import CompareResult, VariantRun
from prc_slam.odometry.guard import FrameHealth, GuardConfig, VariantHealth, judge_variant, no_trust_line

CFG = GuardConfig()


def flags(n: int, flagged: int) -> list[bool]:
    """``n`` frames, the last ``flagged`` of them suspicious."""
    return [False] * (n - flagged) + [True] * flagged


def pair(first: int, frames: int, *suspects: str) -> dict:
    return {"first_frame": first, "frames": frames, "max_difference_m": 40.0, "max_difference_deg": 100.0,
            "suspects": sorted(suspects)}  # fmt: skip


def test_mostly_suspicious_frames_are_not_ok():
    """The VLP-16 drive: 232 of 239 frames flagged was 'ok (239 of 239 frames)'."""
    frames = {"raw": 239}
    h = judge_variant("raw", flags(239, 232), frames, {}, CFG)
    assert h == VariantHealth("untrustworthy", "232 of 239 frames suspicious") and not h.ok
    # the bound is a quarter of the frames: 60 of 240 is still ok, 61 is not
    assert judge_variant("raw", flags(240, 60), {"raw": 240}, {}, CFG).ok
    assert not judge_variant("raw", flags(240, 61), {"raw": 240}, {}, CFG).ok
    assert judge_variant("raw", flags(240, 100), {"raw": 240}, {}, GuardConfig(untrusted_share=0.5)).ok


def test_a_good_run_stays_ok():
    frames = {"raw": 239, "prc": 239}
    few = flags(239, 3)  # isolated flags (a passing vehicle, a degenerate sweep)
    brief = {"prc vs raw": pair(40, 6, "raw")}  # a short disagreement, raw the suspect
    assert judge_variant("raw", few, frames, brief, CFG) == VariantHealth("ok")
    assert judge_variant("prc", [False] * 239, frames, brief, CFG).ok
    assert judge_variant("raw", [], {"raw": 0}, {}, CFG).ok  # nothing registered, nothing flagged


def test_disagreeing_with_every_other_variant_for_most_of_the_run_is_not_ok():
    """raw parts from prc and prc+classaware at frame 5 and never meets them again; its own
    frames are flagged only now and then (the yardstick could not always tell)."""
    frames = {"raw": 239, "prc": 239, "prc+classaware": 239}
    d = {
        "prc vs raw": pair(5, 200, "raw"),
        "prc+classaware vs raw": pair(7, 190, "raw", "prc+classaware"),
        "prc vs prc+classaware": pair(100, 10, "prc+classaware"),
    }
    h = judge_variant("raw", flags(239, 40), frames, d, CFG)
    assert h.status == "untrustworthy"
    assert h.reason == "disagrees with prc and prc+classaware from frame 5 (on 200 of 238 and 190 of 238 frames)"
    # the others disagree with raw but agree with each other: ok
    assert judge_variant("prc", [False] * 239, frames, d, CFG).ok
    assert judge_variant("prc+classaware", flags(239, 20), frames, d, CFG).ok
    # disagreeing with one of the two others only: ok
    assert judge_variant("raw", flags(239, 40), frames, {"prc vs raw": d["prc vs raw"]}, CFG).ok
    # on less than half the shared frames: ok
    half = {k: {**v, "frames": 119} for k, v in d.items()}
    assert judge_variant("raw", flags(239, 40), frames, half, CFG).ok
    # both reasons at once
    both = judge_variant("raw", flags(239, 232), frames, d, CFG)
    assert both.reason.startswith("232 of 239 frames suspicious, disagrees with prc and prc+classaware from frame 5")


def test_a_variant_the_others_lost_is_not_blamed_for_disagreeing():
    """prc holds, raw and prc+classaware diverge (each its own way): prc disagrees with both for
    most of the run, but successive scans sided with prc every time (never a suspect)."""
    frames = {"raw": 7, "prc": 7, "prc+classaware": 7}
    d = {"prc vs raw": pair(1, 6, "raw"), "prc vs prc+classaware": pair(2, 5, "prc+classaware")}
    assert judge_variant("prc", [False] * 7, frames, d, CFG).ok


def test_a_failed_variant_is_not_ok_and_is_held_against_the_others_on_its_frames():
    frames = {"raw": 239, "prc": 20}
    h = judge_variant("prc", [False] * 20, frames, {}, CFG, failed={"frame": 20, "reason": "pose jump of 9 m"})
    assert h == VariantHealth("failed", "failed at frame 20: pose jump of 9 m")
    # raw disagreed with prc on 15 of the 19 frames they shared (and with nobody after): untrustworthy
    d = {"prc vs raw": pair(3, 15, "raw", "prc")}
    assert judge_variant("raw", [False] * 239, frames, d, CFG).reason.startswith("disagrees with prc from frame 3")


def test_the_lead_line_only_when_no_variant_is_ok():
    bad = {
        "raw": VariantHealth("untrustworthy", "232 of 239 frames suspicious"),
        "prc": VariantHealth("untrustworthy", "202 of 239 frames suspicious, disagrees with raw from frame 5"),
        "prc+classaware": VariantHealth("failed", "failed at frame 9: pose jump of 80 m"),
    }
    assert no_trust_line(bad) == (
        "no variant can be trusted on this recording: raw: 232 of 239 frames suspicious; prc: 202 of 239 frames "
        "suspicious, disagrees with raw from frame 5; prc+classaware: failed at frame 9: pose jump of 80 m"
    )
    assert no_trust_line({**bad, "prc": VariantHealth("ok")}) is None
    assert no_trust_line({}) is None


# --------------------------------------------------------------------------------------------
# report.md, metrics.json and the console of a run where every variant went wrong


def _run(name: str, poses: list[np.ndarray], suspicious: list[bool]) -> VariantRun:
    """A variant's record as the compare stage leaves it (its odometry reduced to what is read)."""
    n = len(poses)
    health = [FrameHealth(source_points=1000, inliers=600, mean_residual_m=0.2, threshold_m=0.5) for _ in range(n)]
    for h, s in zip(health, suspicious, strict=True):
        h.suspicious, h.why = s, "disagrees by 9 m" if s else ""
    odometry = SimpleNamespace(
        poses=poses, health=health, health_ms=[0.1] * n, coasted=[], degenerate_frames=[], conditioning=[None] * n
    )
    run = VariantRun(name, odometry)
    run.ms = {"prc": [1.0] * n, "filter": [1.0] * n, "icp": [5.0] * n}
    run.hidden = [0.0] * n
    run.points_in = [1000] * n
    run.points_to_icp = [900] * n
    return run


def _drive(n: int, yaw_deg_per_frame: float, step_m: float) -> list[np.ndarray]:
    poses, T = [], np.eye(4)
    a = np.radians(yaw_deg_per_frame)
    step = np.eye(4)
    step[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    step[0, 3] = step_m
    for _ in range(n):
        poses.append(T.copy())
        T = T @ step
    return poses


@pytest.fixture
def garbage_run() -> CompareResult:
    """Three variants over 40 frames without ground truth that part from frame 2 on and stay
    apart: raw turns 3 deg per frame, prc drives straight, prc+classaware goes 3 times as far;
    most frames of each are flagged, as on the VLP-16 drive."""
    n = 40
    runs = {
        "raw": _run("raw", _drive(n, 3.0, 1.0), flags(n, 36)),
        "prc": _run("prc", _drive(n, 0.0, 1.0), flags(n, 31)),
        "prc+classaware": _run("prc+classaware", _drive(n, 0.0, 3.0), flags(n, 35)),
    }
    d = {
        "prc vs raw": pair(2, 38, "raw", "prc"),
        "prc vs prc+classaware": pair(2, 38, "prc", "prc+classaware"),
        "prc+classaware vs raw": pair(2, 38, "raw", "prc+classaware"),
    }
    times = np.arange(n) * 0.1
    return CompareResult(runs, None, times, [f"{i:06d}" for i in range(n)], disagreements=d)


def test_report_metrics_and_console_lead_with_no_variant_can_be_trusted(garbage_run, tmp_path, caplog):
    """Not every variant 'ok (40 of 40 frames)' in report.md, nothing in metrics.json and no
    warning on the console."""
    metrics, _ = write_compare_outputs(garbage_run, Config(), tmp_path, "drive", write_kitti_poses, write_tum_poses)
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["trusted_variants"] == []
    for name, flagged in (("raw", 36), ("prc", 31), ("prc+classaware", 35)):
        m = saved["variants"][name]
        assert m["health"] == "untrustworthy" and not m["failed"] and m["frames"] == 40  # the old keys stay
        assert m["health_reason"].startswith(f"{flagged} of 40 frames suspicious, disagrees with")
        assert len(m["suspicious_frames"]) == flagged
    lead = saved["no_variant_trusted"]
    assert lead.startswith("no variant can be trusted on this recording: raw: 36 of 40 frames suspicious, ")
    assert "; prc: 31 of 40 frames suspicious, disagrees with raw and prc+classaware from frame 2" in lead
    report = (tmp_path / "report.md").read_text().splitlines()
    assert report[0] == "# drive"
    first = next(line for line in report[1:] if line.strip())
    assert first == f"**{lead}**"
    assert "| raw | **untrustworthy**: 36 of 40 frames suspicious, disagrees with" in "\n".join(report)
    assert not any(" ok (" in line for line in report)
    with caplog.at_level(logging.WARNING, logger="prc_slam"):
        warn_failed(metrics)
    assert caplog.records[0].getMessage() == lead


def test_one_trustworthy_variant_means_no_lead_line(garbage_run, tmp_path, caplog):
    garbage_run.runs["prc"] = _run("prc", _drive(40, 0.0, 1.0), flags(40, 2))
    garbage_run.disagreements = {"prc+classaware vs raw": pair(2, 38, "raw", "prc+classaware")}
    metrics, _ = write_compare_outputs(garbage_run, Config(), tmp_path, "drive", write_kitti_poses, write_tum_poses)
    assert metrics["trusted_variants"] == ["prc"] and "no_variant_trusted" not in metrics
    assert metrics["variants"]["prc"]["health"] == "ok" and metrics["variants"]["prc"]["health_reason"] is None
    report = (tmp_path / "report.md").read_text()
    assert "no variant can be trusted" not in report and "| prc | ok (40 of 40 frames) |" in report
    with caplog.at_level(logging.WARNING, logger="prc_slam"):
        warn_failed(metrics)
    said = [r.getMessage() for r in caplog.records]
    # raw and prc+classaware disagree with each other, not with prc: only their flagged frames count
    assert said[:2] == [
        "odometry raw is untrustworthy: 36 of 40 frames suspicious",
        "odometry prc+classaware is untrustworthy: 35 of 40 frames suspicious",
    ]
    assert not any("no variant" in s for s in said)
