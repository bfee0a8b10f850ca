"""Frame and point times: per-point times relative to each sweep or on another clock than
``times.txt`` or the ROS header stamp, float32 time fields, repeated or unset header stamps
and gaps in the frame times.
"""

from __future__ import annotations

import itertools
import logging

import numpy as np
import pytest

from data_tools.formats.pcd import SweepFolder, sweep_relative, write_pcd
from data_tools.formats.rosbag import cloud_from_records, cloud_to_scan
from data_tools.organize import Organizer
from tests.inputs.grids import spinning_grid, write_room_sweeps
from tests.inputs.kitti import kitti_folder
from tests.inputs.pointcloud2 import EPOCH_NS, VELODYNE_LAYOUT, vlp16_records


def test_sweep_relative_hand_cases():
    assert sweep_relative(np.array([0.0, 0.05, 0.1]))  # from the sweep's start (Ouster t)
    assert sweep_relative(np.array([-0.1, -0.05, 0.0]))  # to the sweep's end (Velodyne time)
    assert sweep_relative(np.array([np.nan, 0.0, 0.099]))
    assert not sweep_relative(np.array([0.1, 0.15, 0.2]))  # sweep 1 on a clock shared by the sweeps
    assert not sweep_relative(np.array([1.7e9, 1.7e9 + 0.1]))  # epoch seconds
    assert not sweep_relative(np.array([np.nan, np.nan]))


@pytest.mark.parametrize(
    ("name", "values"),
    [
        ("t", (np.arange(720) * 0.1 / 720 * 1e9).astype(np.uint32)),  # Ouster: ns from the sweep start
        ("time", (np.arange(720) * 0.1 / 720 - 0.1).astype(np.float32)),  # Velodyne: s to the sweep end
    ],
)
def test_sweep_relative_point_times_give_increasing_frame_times(tmp_path, caplog, name, values):
    """Without times.txt, sweep i starts at i x 0.1 s (before: every frame at ~0 s)."""
    write_room_sweeps(tmp_path, 3, {name: values[None, :]})
    seq = SweepFolder(tmp_path)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        scans = [seq[i] for i in range(3)]
    frame_times = np.array([s.meta["frame_time"] for s in scans])
    assert np.all(np.diff(frame_times) > 0.05), frame_times
    np.testing.assert_allclose(np.diff(frame_times), 0.1, atol=1e-6)
    ends = [(float(np.nanmin(s.point_times())), float(np.nanmax(s.point_times()))) for s in scans]
    for (_, hi), (lo, _) in itertools.pairwise(ends):
        assert lo > hi - 1e-3  # one sweep's points before the next one's
    warned = [r for r in caplog.records if "restart with every sweep" in r.getMessage()]
    assert len(warned) == 1 and name in warned[0].getMessage()


def test_shared_clock_point_times_are_kept(tmp_path):
    """Per-point times on a clock shared by the sweeps (epoch s) are not shifted."""
    col_t = 1.7e9 + np.arange(720) * 0.1 / 720
    write_room_sweeps(tmp_path, 1, {"timestamp": col_t[None, :]})
    scan = SweepFolder(tmp_path)[0]
    assert scan.meta["frame_time"] == pytest.approx(1.7e9, abs=1e-3)


def test_point_times_on_another_clock_than_times_txt_are_rebased(tmp_path, caplog):
    """times.txt from 0 beside per-point epoch times: before, the scans carried frame times 0.1 s
    apart and point times 1.7e9 s (odometry then stopped: 'registration impossible')."""
    col_t = np.arange(720) * 0.1 / 720
    for i in range(3):
        write_room_sweeps(tmp_path, 1, {"timestamp": (1.7e9 + i * 0.1 + col_t)[None, :]})
        (tmp_path / "000000.pcd").rename(tmp_path / f"s{i}.pcd")
    np.savetxt(tmp_path / "times.txt", [0.0, 0.1, 0.2])
    seq = SweepFolder(tmp_path)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        scans = [seq[i] for i in range(3)]
    for i, s in enumerate(scans):
        t = s.point_times()
        assert s.meta["frame_time"] == pytest.approx(0.1 * i)
        assert 0.1 * i - 1e-6 <= np.nanmin(t) and np.nanmax(t) <= 0.1 * i + 0.1 + 1e-6
    assert sum("another clock" in r.getMessage() for r in caplog.records) == 1


def ros_sweep(time_values: np.ndarray, stamp_ns: int):
    """A 16-beam sweep as a Velodyne-layout PointCloud2 (x y z ring timestamp[f8]), firing order."""
    grid = spinning_grid(16, 720)
    pts = np.swapaxes(grid, 0, 1).reshape(-1, 3)
    ok = np.isfinite(pts).all(axis=1)
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", "<u2"), ("timestamp", "<f8")])
    rec = np.zeros(int(ok.sum()), dt)
    rec["x"], rec["y"], rec["z"] = pts[ok].T
    rec["ring"] = np.tile(np.arange(16), 720)[ok]
    rec["timestamp"] = np.repeat(time_values, 16)[ok]
    return cloud_from_records(rec, stamp_ns=stamp_ns)


@pytest.mark.parametrize("base", [1.2e9, 5000.0])  # another epoch; the sensor's uptime
def test_ros_point_times_on_another_clock_start_at_the_header_stamp(base, caplog):
    """Point times on another clock than the header stamp (5e8 s before or 5000 s after it) are rebased so that
    the sweep starts at the stamp."""
    from data_tools.formats.rosbag import detect_time_field

    col_t = np.arange(720) * 0.1 / 720
    stamp_ns = 1_700_000_000 * 10**9
    cloud = ros_sweep(base + col_t, stamp_ns)
    tf = detect_time_field(cloud, 0.1)
    with caplog.at_level(logging.WARNING, logger="prc_slam.rosbag"):
        scan = cloud_to_scan(cloud, Organizer(), name="0", source="mem", time_field=tf)
        cloud_to_scan(ros_sweep(base + 0.1 + col_t, stamp_ns + 10**8), Organizer(), name="1", source="m", time_field=tf)
    t = scan.point_times()
    assert np.nanmin(t) == pytest.approx(1.7e9, abs=1e-6)
    assert np.nanmax(t) - np.nanmin(t) == pytest.approx(col_t[-1], abs=1e-6)
    assert sum("another clock" in r.getMessage() for r in caplog.records) == 1 and tf.rebased == 2


def test_ros_point_times_relative_to_the_sweep_end_are_kept():
    from data_tools.formats.rosbag import detect_time_field

    col_t = np.arange(720) * 0.1 / 720 - 0.1  # Velodyne driver: s before the stamp (sweep end)
    cloud = ros_sweep(col_t, 1_700_000_000 * 10**9)
    tf = detect_time_field(cloud, 0.1)
    t = cloud_to_scan(cloud, Organizer(), name="0", source="mem", time_field=tf).point_times()
    assert np.nanmax(t) == pytest.approx(1.7e9 - 0.1 / 720, abs=1e-6) and tf.rebased == 0


def test_float32_epoch_time_field_is_ignored_with_a_warning(tmp_path, caplog):
    """A float32 'timestamp' of epoch seconds (resolution 128 s): before, every point and every
    sweep got the same time and odometry stopped at frame 1 ('does not follow')."""
    col_t = np.arange(720) * 0.1 / 720
    for i in range(2):
        write_room_sweeps(tmp_path, 1, {"timestamp": (1.7e9 + i * 0.1 + col_t).astype(np.float32)[None, :]})
        (tmp_path / "000000.pcd").rename(tmp_path / f"s{i}.pcd")
    seq = SweepFolder(tmp_path)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        scans = [seq[i] for i in range(2)]
    assert all(s.timestamps is None for s in scans)
    assert sum("cannot time the points" in r.getMessage() for r in caplog.records) == 1


@pytest.mark.parametrize(
    "values",
    [
        (np.arange(720) * 0.1 / 720).astype(np.float32),  # s from the sweep start
        (np.arange(720) * 0.1 / 720 * 1e9).astype(np.float32),  # ns as float32
    ],
)
def test_float32_relative_time_fields_are_kept(tmp_path, values):
    write_room_sweeps(tmp_path, 1, {"time": values[None, :]})
    scan = SweepFolder(tmp_path)[0]
    t = scan.point_times()
    assert t is not None and np.nanmax(t) - np.nanmin(t) == pytest.approx(0.1 * 719 / 720, abs=1e-5)


def test_recording_whose_header_stamps_repeat_is_warned_on_opening(tmp_path, caplog):
    """A driver that stamps two sweeps alike: odometry stops at the second; the reader says so
    when it opens the recording (before: nothing until the odometry's own failure)."""
    from data_tools.formats.rosbag import RosbagSequence
    from data_tools.formats.stream_out import RosCloudWriter

    col_t = np.arange(720) * 0.1 / 720 - 0.1
    stamps = [10**18, 10**18 + 10**8, 10**18 + 10**8]
    with RosCloudWriter(tmp_path / "r.bag", "ros1", "/points") as w:
        for k, st in enumerate(stamps):
            w.write_cloud(ros_sweep(col_t, st), log_time_ns=st + k)
    with caplog.at_level(logging.WARNING, logger="prc_slam.rosbag"):
        seq = RosbagSequence(tmp_path / "r.bag")
    assert len(seq) == 3
    lines = [r.getMessage() for r in caplog.records if "do not increase" in r.getMessage()]
    assert len(lines) == 1 and "1 of 3 header stamps" in lines[0] and "message 2" in lines[0]


def test_a_gap_in_the_frame_times_is_warned(tmp_path, caplog):
    """Sweeps 0-3 and 10-15 of KITTI 00 with their ``times.txt`` (0.7 s missing) are warned of the gap."""
    from data_tools.formats.kitti import KittiSequence
    from data_tools.formats.pcd import SweepFolder
    from data_tools.formats.trajectory_io import warn_time_gaps

    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        assert warn_time_gaps(np.arange(10) * 0.1, "even") == 0
        assert warn_time_gaps(np.array([0.0, 0.1, 0.2, 0.3, 5.3, 5.4, 5.5]), "gap") == 1
        assert warn_time_gaps(np.array([0.0, 0.1, 0.9]), "too short to tell") == 0
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["gap"]
    assert "5 s between frames 3 and 4 (50.0 x the median step of 0.1 s)" in caplog.records[0].getMessage()
    caplog.clear()
    root = kitti_folder(tmp_path / "seq", [0, 1, 2, 3, 10, 11, 12], 16)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        seq = KittiSequence(root)
    assert "times.txt: 1 gap in the frame times, the largest 0.7 s between frames 3 and 4" in caplog.text
    caplog.clear()
    folder = tmp_path / "pcd"
    folder.mkdir()
    for i in range(5):
        g = seq[i].points()
        write_pcd(folder / f"{i:06d}.pcd", {"x": g[:, 0], "y": g[:, 1], "z": g[:, 2]})
    np.savetxt(folder / "times.txt", [0.0, 0.1, 0.2, 0.3, 2.0])
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        SweepFolder(folder)
    assert "times.txt: 1 gap in the frame times, the largest 1.7 s" in caplog.text


def test_a_recording_whose_header_stamps_are_unset_is_timed_by_its_log_times(tmp_path, caplog):
    """Every header stamp 0 (a driver that leaves them unset): the log times time the frames, and the messages
    written back keep their own stamps."""
    from data_tools.formats.rosbag import RosbagSequence, cloud_from_records
    from data_tools.formats.stream_out import RosCloudWriter

    rec = vlp16_records(VELODYNE_LAYOUT, 22)
    path = tmp_path / "unset stamps.mcap"
    with RosCloudWriter(path, "mcap", "/points") as w:
        for k in range(3):
            w.write_cloud(cloud_from_records(rec, stamp_ns=0), log_time_ns=EPOCH_NS + k * 100_000_000)
    with caplog.at_level(logging.WARNING):
        seq = RosbagSequence(path)
    assert any("header stamps" in r.getMessage() and "log times" in r.getMessage() for r in caplog.records)
    np.testing.assert_allclose(seq.times - 1.7e9, [0.0, 0.1, 0.2], atol=1e-6)
    scans = list(seq)
    for k, scan in enumerate(scans):
        assert scan.meta["frame_time"] == pytest.approx(1.7e9 + 0.1 * k, abs=1e-6)
        assert scan.meta["ros"].stamp == 0.0  # the recorded message, for writers
        t = scan.point_times()
        assert t is not None and abs(np.nanmax(t) - scan.meta["frame_time"]) < 0.01  # the sweep ends at its stamp
    seq.close()
