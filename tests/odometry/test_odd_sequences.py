"""Sequences that strain the odometry commands (``compare`` and ``odometry``): each test builds a small
sequence in ``tmp_path`` (KITTI 00 sweeps copied and rearranged, decoded Ouster sweeps, PCD sweeps)
and checks that every variant finishes or is marked failed with a reason, that a divergence is
flagged at its frame, and that the outputs say nothing false: frame times of sweeps without
times, runs too short to score, frames missing with their times known, pose and time files that
do not match the sweeps, and strided sweeps.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from data_tools.formats.pcd import write_pcd
from prc_slam.cli import app
from tests.inputs.grids import write_room_sweeps
from tests.inputs.kitti import kitti_folder


def test_failed_odometry_variant_is_warned(caplog):
    from prc_slam.cli.compare import warn_failed

    metrics = {
        "frames": 6,
        "variants": {
            "raw": {"frames": 6, "failed": False},
            "prc": {"frames": 5, "failed": True, "failed_at_frame": 5, "failure_reason": "frame time 0.5 s repeats"},
        },
    }
    with caplog.at_level(logging.WARNING, logger="prc_slam"):
        warn_failed(metrics)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1
    assert "prc stopped at frame 5 of 6: frame time 0.5 s repeats" in lines[0] and "5 poses" in lines[0]


def test_odometry_on_pcd_sweeps_with_relative_times_uses_every_frame(tmp_path):
    """End to end: PCD sweeps with per-sweep relative point times and no ``times.txt`` are registered frame by
    frame by every variant (a pose per frame), not stopped at frame 1."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    (tmp_path / "in").mkdir()
    write_room_sweeps(tmp_path / "in", 3, {"t": (np.arange(720) * 0.1 / 720 * 1e9).astype(np.uint32)[None, :]})
    poses = tmp_path / "poses.tum"
    res = CliRunner().invoke(
        app, ["odometry", str(tmp_path / "in"), "--poses-out", str(poses), "--pose-format", "tum", "--filter", "none"]
    )
    assert res.exit_code == 0, res.output
    tum = np.loadtxt(poses, ndmin=2)
    assert len(tum) == 3
    np.testing.assert_allclose(np.diff(tum[:, 0]), 0.1, atol=1e-6)
    assert np.isfinite(tum).all()


def test_a_run_too_short_for_the_health_checks_says_so(tmp_path):
    """``compare --stride 5`` on KITTI 00 (four keyframes, fewer than ``warm_up``): report.md, metrics.json and
    the command line say that nothing was checked, rather than calling every variant 'ok'."""
    import json

    from typer.testing import CliRunner

    from prc_slam.cli import app
    from prc_slam.jobs.odometry import unchecked_health_note
    from prc_slam.odometry.guard import GuardConfig

    warm_up = GuardConfig().warm_up
    assert unchecked_health_note(warm_up + 1, warm_up) is None and unchecked_health_note(None, warm_up) is None
    assert "only 1 frame:" in unchecked_health_note(1, warm_up)
    root = kitti_folder(tmp_path / "seq", [0, 1, 2], 3)
    res = CliRunner().invoke(app, ["compare", str(root), "--variants", "raw", "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert "only 3 frames: the health checks" in " ".join(res.output.split())
    assert "only 3 frames" in json.loads((tmp_path / "out" / "metrics.json").read_text())["health_note"]
    assert "**Health not checked**: only 3 frames" in (tmp_path / "out" / "report.md").read_text()


def _kitti_copy(kitti: Path, root: Path, numbers: list[int], replace: dict[int, np.ndarray] | None = None) -> Path:
    """KITTI 00's sweeps ``numbers`` under their own names, with the full poses/times/calib; a
    sweep in ``replace`` is written with the given ``float32 (N, 4)`` points instead."""
    (root / "velodyne").mkdir(parents=True)
    for k in numbers:
        dst = root / "velodyne" / f"{k:06d}.bin"
        if replace and k in replace:
            replace[k].astype(np.float32).tofile(dst)
        else:
            shutil.copy(kitti / "velodyne" / f"{k:06d}.bin", dst)
    for name in ("poses.txt", "times.txt", "calib.txt"):
        shutil.copy(kitti / name, root / name)
    return root


def _compare(root: Path, out: Path, variants: str = "raw") -> dict:
    res = CliRunner().invoke(app, ["compare", str(root), "--variants", variants, "--out", str(out)])
    assert res.exit_code == 0, res.output
    return json.loads((out / "metrics.json").read_text())


def _frames_txt(out: Path) -> np.ndarray:
    return np.loadtxt(out / "frames.txt", usecols=1, ndmin=1)


def test_ouster_sweeps_are_written_at_their_own_times(ouster_files, tmp_path):
    """The OS-1 sweeps (0.1 s apart, at 991.6 s on the sensor's clock) are written to ``frames.txt`` and the TUM
    trajectories at their own times, not at their frame indices."""
    folder = tmp_path / "os1"
    folder.mkdir()
    for f in ouster_files:
        if "OS-1-128_lb_n3" in f.name:
            shutil.copy(f, folder / f.name)
    out = tmp_path / "out"
    metrics = _compare(folder, out, "raw,prc")
    assert all(not m["failed"] and m["frames"] == 3 for m in metrics["variants"].values())
    times = _frames_txt(out)
    np.testing.assert_allclose(np.diff(times), 0.1, atol=1e-3)
    assert 991.5 < times[0] < 991.7
    for name in ("raw", "prc"):
        np.testing.assert_allclose(np.loadtxt(out / f"{name}_poses_tum.txt")[:, 0], times, atol=1e-6)


def test_the_reference_time_is_the_frame_time_else_the_middle_of_all_points():
    """A frame's reference time is its ``frame_time``, else the middle of all its points' times, one instant for
    every variant (not the middle of the points a PRC variant registered)."""
    from prc_slam.odometry.compare import _frame_time
    from prc_slam.scan import Scan, SpinningSensor

    sensor = SpinningSensor.create(np.radians([-5.0, 5.0]), 4)
    times = np.array([[10.0, 10.1, 10.2, 10.3]] * 2)
    scan = Scan(ranges=np.full((2, 4), 5.0, np.float32), sensor=sensor, timestamps=times)
    assert _frame_time(scan, scan.point_times()) == pytest.approx(10.15)
    assert _frame_time(scan, np.array([10.0, np.nan, 10.3])) == pytest.approx(10.15)
    scan.meta["frame_time"] = 3.0
    assert _frame_time(scan, scan.point_times()) == 3.0
    assert _frame_time(Scan(ranges=np.full((2, 4), 5.0, np.float32), sensor=sensor), None) is None


def test_a_single_frame_has_no_error_figures(kitti_dir, tmp_path):
    """One KITTI sweep has no ``ate_rmse_m`` or ``rpe_trans_m`` (null, '-' in the tables): its one pose is
    placed at the ground truth by construction, so 0.0 would be a false perfect score."""
    out = tmp_path / "out"
    metrics = _compare(_kitti_copy(kitti_dir, tmp_path / "seq", [0]), out)
    raw = metrics["variants"]["raw"]
    assert raw["frames"] == 1 and raw["ate_rmse_m"] is None and raw["rpe_trans_m"] is None
    assert "| raw | - | - |" in (out / "report.md").read_text()


def test_se3_exp_inverts_se3_log():
    from scipy.spatial.transform import Rotation

    from prc_slam.odometry.kiss import se3_exp, se3_log

    for seed in range(4):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
        T[:3, 3] = np.random.default_rng(seed).normal(size=3)
        np.testing.assert_allclose(se3_exp(se3_log(T)), T, atol=1e-9)
    np.testing.assert_allclose(se3_exp(np.zeros(6)), np.eye(4))


def test_the_prediction_follows_the_time_since_the_previous_frame():
    """The constant-velocity prediction is stretched to the time since the previous frame when that interval
    differs from the last one by more than 1.5x."""
    from prc_slam.odometry.kiss import KissOdometry

    odo = KissOdometry()
    delta = np.eye(4)
    delta[0, 3] = 0.86
    for t in (0.0, 0.1, 0.2, 0.3):
        odo.clock.next(t, None)
    assert odo._predicted_motion(delta) is delta  # steady rate: KISS-ICP's prediction, untouched
    odo.clock.next(1.0, None)  # 0.7 s since the previous frame
    np.testing.assert_allclose(odo._predicted_motion(delta)[:3, 3], [6.02, 0.0, 0.0], atol=1e-9)


def test_frames_missing_with_their_times_are_bridged(kitti_dir, tmp_path):
    """KITTI 00 sweeps 0-4 and 12-15 with their times (0.8 s and 6.9 m between 4 and 12): the PRC variant
    predicts across the gap and stays within the raw variant's error (ATE 0.45 m) instead of locking 5 m short."""
    root = _kitti_copy(kitti_dir, tmp_path / "seq", [0, 1, 2, 3, 4, 12, 13, 14, 15])
    prc = _compare(root, tmp_path / "out", "prc")["variants"]["prc"]
    assert not prc["failed"] and prc["frames"] == 9
    assert prc["ate_rmse_m"] < 0.8, prc["ate_rmse_m"]
    assert prc["suspicious_frames"] == []


def test_unnumbered_sweeps_beside_a_longer_pose_file_are_warned(kitti_dir, tmp_path, caplog):
    """Sweeps named ``a.bin``, ``b.bin`` beside KITTI 00's 16 poses take the first poses with a warning
    (whichever sweeps they are)."""
    from data_tools.formats.kitti import KittiSequence

    root = _kitti_copy(kitti_dir, tmp_path / "seq", [])
    for name, k in (("a", 7), ("b", 8)):
        shutil.copy(kitti_dir / "velodyne" / f"{k:06d}.bin", root / "velodyne" / f"{name}.bin")
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        seq = KittiSequence(root)
    assert len(seq.poses) == 2
    assert "16 poses for 2 scans whose names are not frame numbers (e.g. a.bin)" in caplog.text
    assert "16 times for 2 scans" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        KittiSequence(_kitti_copy(kitti_dir, tmp_path / "numbered", [0, 1]))
    assert "not frame numbers" not in caplog.text


@pytest.mark.parametrize(("scale", "offset", "warned"), [(1e3, 0.0, True), (1e9, 1.3e18, True), (1.0, 1.3e9, False)])
def test_frame_times_in_milliseconds_or_nanoseconds_are_warned(kitti_dir, tmp_path, caplog, scale, offset, warned):
    """A ``times.txt`` in milliseconds or nanoseconds (ROS stamps) is warned, as the guard's speed bound, the
    TUM files and ``frames.txt`` read it as seconds; epoch seconds are seconds (not warned)."""
    from data_tools.formats.kitti import KittiSequence

    root = _kitti_copy(kitti_dir, tmp_path / "seq", [0, 1, 2])
    np.savetxt(root / "times.txt", offset + scale * np.loadtxt(kitti_dir / "times.txt"), fmt="%.6f")
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        KittiSequence(root)
    assert ("times not in seconds?" in caplog.text) is warned, caplog.text


def _turned(kitti: Path, k: int) -> np.ndarray:
    """Sweep ``k`` turned by 180 deg about z: a frame from elsewhere (a relocalisation jump)."""
    pts = np.fromfile(kitti / "velodyne" / f"{k:06d}.bin", np.float32).reshape(-1, 4).copy()
    pts[:, :2] *= -1
    return pts


@pytest.mark.parametrize("case", ["empty", "nan", "turned"])
def test_a_bad_sweep_mid_sequence_is_flagged_at_its_frame(kitti_dir, tmp_path, case):
    """An empty or all-NaN sweep at frame 6 takes the predicted pose and is flagged; a sweep turned by 180 deg
    (a frame from elsewhere) is flagged at that frame by its residual. The variant finishes, and the outputs
    hold one line per frame."""
    bad = {
        "empty": np.zeros((0, 4)),
        "nan": np.full((1000, 4), np.nan),
        "turned": _turned(kitti_dir, 2),
    }[case]
    out = tmp_path / "out"
    metrics = _compare(_kitti_copy(kitti_dir, tmp_path / "seq", list(range(9)), {6: bad}), out)
    raw = metrics["variants"]["raw"]
    assert not raw["failed"] and raw["frames"] == 9 == len(_frames_txt(out))
    assert raw["first_suspicious_frame"] == 6, raw["first_suspicious_reason"]
    assert (raw["coasted_frames"] == [6]) is (case != "turned")
    assert len(np.loadtxt(out / "raw_poses_tum.txt")) == 9
    assert "| raw | ok (9 of 9 frames) | 6 (`000006`) |" in (out / "report.md").read_text()


def test_strided_pcd_sweeps_without_times_keep_their_spacing(kitti_dir, tmp_path):
    """KITTI 00 sweeps as PCDs without times, every 5th: sweep i is timed at i periods (keyframes 0.5 s apart),
    so the TUM files and the guard's speed bound use 0.5 s."""
    from prc_slam.jobs.common import open_input

    folder = tmp_path / "pcd"
    folder.mkdir()
    for k in range(11):
        p = np.fromfile(kitti_dir / "velodyne" / f"{k:06d}.bin", np.float32).reshape(-1, 4)
        write_pcd(folder / f"{k:06d}.pcd", {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2]})
    ds, n = open_input(folder, stride=5)
    times = [ds[i].meta["frame_time"] for i in range(n)]
    np.testing.assert_allclose(np.diff(times), 0.5, atol=1e-6)
