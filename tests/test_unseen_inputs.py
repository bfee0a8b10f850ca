"""Inputs from sensors and tools the project did not read at first: each test generates a small input in
``tmp_path`` and checks the readers organise it right, or say clearly why they cannot.

- PCD sweeps whose per-point times restart with every sweep (Ouster ``t``, Livox ``offset_time``,
  Velodyne ``time`` <= 0) and no ``times.txt``: frame times must still increase (they were all
  equal, and odometry stopped at frame 1 with exit code 0).
- Organised clouds written one firing per row (``HEIGHT`` = columns, ``WIDTH`` = beams): they
  were organised into ``columns`` rings of ``beams`` columns without a warning.
- Livox's ``line`` field (the laser of a non-repetitive pattern) was taken as a ring: a rosette
  became a 6-ring range image of 200,000 columns and 95 % noise, without a warning.
- A failed odometry variant now gives a warning on the command line.
"""

from __future__ import annotations

import itertools
import logging
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data_tools import DataError
from data_tools.formats.pcd import SweepFolder, rows_are_scan_lines, sweep_relative, write_pcd
from data_tools.formats.rosbag import cloud_from_records, cloud_to_scan
from data_tools.organize import Organizer

ELEVATION_DEG = np.linspace(15.0, -15.0, 16)


def spinning_grid(beams: int = 16, cols: int = 720, fov_deg: float = 30.0, seed: int = 0) -> np.ndarray:
    """One sweep of a spinning sensor as an organised grid ``(beams, cols, 3)`` (rows = rings, top
    beam first) in a round room (walls 12-18 m, floor 1.8 m below); about 5 % no returns (NaN)."""
    rng = np.random.default_rng(seed)
    el = np.radians(np.linspace(fov_deg / 2, -fov_deg / 2, beams))[:, None]
    az = (2 * np.pi * (np.arange(cols) + 0.5) / cols)[None, :]
    r = (15.0 + 3.0 * np.sin(3.0 * az)) / np.cos(el)
    r = np.minimum(r, np.where(el < 0, 1.8 / np.maximum(-np.sin(el), 1e-9), np.inf))
    xyz = np.stack(np.broadcast_arrays(r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)), -1)
    xyz = xyz.astype(np.float32)
    xyz[rng.random((beams, cols)) < 0.05] = np.nan
    return xyz


def flat_fields(grid: np.ndarray) -> dict[str, np.ndarray]:
    g = grid.reshape(-1, 3)
    return {"x": g[:, 0], "y": g[:, 1], "z": g[:, 2]}


# ------------------------------------------------------------------ per-point times per sweep


def test_sweep_relative_hand_cases():
    assert sweep_relative(np.array([0.0, 0.05, 0.1]))  # from the sweep's start (Ouster t)
    assert sweep_relative(np.array([-0.1, -0.05, 0.0]))  # to the sweep's end (Velodyne time)
    assert sweep_relative(np.array([np.nan, 0.0, 0.099]))
    assert not sweep_relative(np.array([0.1, 0.15, 0.2]))  # sweep 1 on a clock shared by the sweeps
    assert not sweep_relative(np.array([1.7e9, 1.7e9 + 0.1]))  # epoch seconds
    assert not sweep_relative(np.array([np.nan, np.nan]))


def write_room_sweeps(root: Path, n: int, time_field: dict[str, np.ndarray] | None) -> list[int]:
    """``n`` unorganised 16-beam sweeps in firing order (no-returns dropped); returns their sizes."""
    sizes = []
    for i in range(n):
        grid = spinning_grid(seed=i)
        fields = flat_fields(np.swapaxes(grid, 0, 1))  # firing order: all beams of a column together
        ok = np.isfinite(fields["x"])
        fields = {k: v[ok] for k, v in fields.items()}
        if time_field is not None:
            fields.update(
                {k: np.swapaxes(np.broadcast_to(v, grid.shape[:2]), 0, 1).ravel()[ok] for k, v in time_field.items()}
            )
        write_pcd(root / f"{i:06d}.pcd", fields)
        sizes.append(int(ok.sum()))
    return sizes


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


# ------------------------------------------------------------------ organised clouds, one firing per row


@settings(max_examples=15, deadline=None)
@given(
    beams=st.sampled_from([8, 16, 32, 64, 128]),
    cols=st.sampled_from([360, 512, 1024, 1800]),
    fov=st.floats(10.0, 90.0),
    seed=st.integers(0, 10),
)
def test_rows_are_scan_lines_of_any_spinning_sensor_and_not_of_its_transpose(beams, cols, fov, seed):
    grid = spinning_grid(beams, cols, fov, seed)
    assert rows_are_scan_lines(grid)
    assert not rows_are_scan_lines(np.ascontiguousarray(np.swapaxes(grid, 0, 1)))


def test_rows_are_scan_lines_of_real_ouster_sweeps(ouster_files):
    """The decoded Ouster sweeps (not destaggered: beams' azimuth offsets) keep their rows."""
    for f in ouster_files:
        xyz = np.load(f)["xyz_lidar_m"]
        assert rows_are_scan_lines(xyz), f.name
        assert not rows_are_scan_lines(np.ascontiguousarray(np.swapaxes(xyz, 0, 1))), f.name


def test_rows_are_scan_lines_of_a_forward_solid_state_grid():
    """A forward-looking grid (120 deg wide, 25 deg high, e.g. Hesai AT128) keeps its rows."""
    el = np.radians(np.linspace(12.5, -12.5, 64))[:, None]
    az = np.radians(np.linspace(-60, 60, 600))[None, :]
    d = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), -1)
    grid = d * 30.0
    assert rows_are_scan_lines(grid)
    assert not rows_are_scan_lines(np.ascontiguousarray(np.swapaxes(grid, 0, 1)))


def organised_pair(tmp_path: Path) -> tuple[SweepFolder, SweepFolder, np.ndarray]:
    grid = spinning_grid(16, 720)
    rows_dir, firing_dir = tmp_path / "rows", tmp_path / "firings"
    rows_dir.mkdir()
    firing_dir.mkdir()
    write_pcd(rows_dir / "000000.pcd", flat_fields(grid), height=16)
    write_pcd(firing_dir / "000000.pcd", flat_fields(np.swapaxes(grid, 0, 1)), height=720)
    return SweepFolder(rows_dir), SweepFolder(firing_dir), grid


def test_organised_pcd_with_one_firing_per_row_is_organised_by_rings(tmp_path, caplog):
    """Before: a 720 x 16 range image (720 'rings' of 16 columns), one warning about row order."""
    by_rows, by_firings, grid = organised_pair(tmp_path)
    ref = by_rows[0]
    with caplog.at_level(logging.WARNING):
        scan = by_firings[0]
    assert ref.shape == (16, 720)
    assert scan.shape == (16, 720)
    assert any("rows are not scan lines" in r.getMessage() for r in caplog.records)
    # one label per input point, in input order: each point's row is its beam (top beam = row 0)
    rows = np.broadcast_to(np.arange(16)[:, None], (16, 720)).astype(np.int64)
    beam_of_point = np.swapaxes(rows, 0, 1).ravel()
    slot_rows = scan.per_point(np.broadcast_to(np.arange(16)[:, None], scan.shape))
    assert len(slot_rows) == 16 * 720 == scan.n_points
    ok = np.isfinite(np.swapaxes(grid, 0, 1).reshape(-1, 3)).all(axis=1)
    assert np.array_equal(slot_rows[ok], beam_of_point[ok])


def test_organised_ros_cloud_with_one_firing_per_row_is_organised_by_rings():
    grid = spinning_grid(16, 720)
    firings = np.ascontiguousarray(np.swapaxes(grid, 0, 1)).reshape(-1, 3)
    rec = np.zeros(len(firings), np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")]))
    rec["x"], rec["y"], rec["z"] = firings.T
    cloud = cloud_from_records(rec, height=720, is_dense=False)
    cache: dict[tuple[int, int], bool] = {}
    scan = cloud_to_scan(cloud, Organizer(), name="000000", source="mem", row_lines=cache)
    assert scan.shape == (16, 720)
    assert cache == {(720, 16): False}
    ok = np.isfinite(firings).all(axis=1)
    slot_rows = scan.per_point(np.broadcast_to(np.arange(16)[:, None], scan.shape))
    assert np.array_equal(slot_rows[ok], np.tile(np.arange(16), 720)[ok])
    # the same cloud organised row by row stays organised
    rec2 = np.zeros(16 * 720, rec.dtype)
    rec2["x"], rec2["y"], rec2["z"] = grid.reshape(-1, 3).T
    scan2 = cloud_to_scan(cloud_from_records(rec2, height=16, is_dense=False), Organizer(), name="0", source="mem")
    assert scan2.shape == (16, 720) and scan2.meta["organize"]["method"] == "organized"


# ------------------------------------------------------------------ Livox


def rosette(n: int = 20000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A Livox-like non-repetitive rosette (38.4 deg, forward): a floor 1.5 m below, a wall at 25 m."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100000.0
    rr = 0.5 * np.radians(38.4) * np.sin(2 * np.pi * 1234.5 * t)
    az, el = rr * np.cos(2 * np.pi * 987.6 * t), rr * np.sin(2 * np.pi * 987.6 * t)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    r = np.minimum(np.where(d[:, 2] < -1e-3, -1.5 / np.minimum(d[:, 2], -1e-3), np.inf), 25.0 / d[:, 0])
    return (d * (r + rng.normal(0, 0.02, n))[:, None]).astype(np.float32), t


def test_livox_line_field_is_not_taken_as_rings(tmp_path):
    """Before: 6 'rings' of ~200,000 columns for 20,000 points, 95 % noise, no warning."""
    xyz, t = rosette()
    write_pcd(
        tmp_path / "000000.pcd",
        {
            "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
            "line": (np.arange(len(xyz)) % 6).astype(np.uint8),
            "offset_time": (t * 1e9).astype(np.uint32),
        },
    )  # fmt: skip
    with pytest.raises(DataError, match="cannot organise"):
        SweepFolder(tmp_path)[0]


def test_livox_line_field_in_a_ros_cloud_is_not_taken_as_rings():
    xyz, _ = rosette()
    rec = np.zeros(len(xyz), np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("line", "u1")]))
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["line"] = np.arange(len(xyz)) % 6
    with pytest.raises(DataError, match="cannot organise"):
        cloud_to_scan(cloud_from_records(rec), Organizer(), name="0", source="mem")


# ------------------------------------------------------------------ command line


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
    """End to end: before, the PRC variant stopped at frame 1 ('frame time ... does not follow')
    and the command exited 0 with one pose."""
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


# ------------------------------------------------------------------ map clouds


def write_las_cloud(path: Path, x: np.ndarray, y: np.ndarray, z: np.ndarray, scale: float) -> Path:
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale, scale, scale])
    header.offsets = np.array([x.min(), y.min(), z.min()])
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.write(path)
    return path


def block_scene(n: int = 2000, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground over 100 x 100 m with a 10 m high block."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 100, n), rng.uniform(0, 100, n)
    z = np.where((x > 30) & (x < 50) & (y > 30) & (y < 60), 10.0, 0.0) + rng.normal(0, 0.03, n)
    return x, y, z


def test_map_cloud_in_geographic_degrees_is_refused(tmp_path):
    """Before: lon/lat in degrees with heights in metres classified as 84 % poles, no warning."""
    from data_tools.formats.clouds import cloud_chunks

    x, y, z = block_scene()
    path = write_las_cloud(tmp_path / "deg.las", 11.0 + x / 111_000, 48.0 + y / 111_000, z, 1e-7)
    with pytest.raises(DataError, match="geographic degrees"):
        list(cloud_chunks(path))
    np.save(tmp_path / "deg.npy", np.column_stack([11.0 + x / 111_000, 48.0 + y / 111_000, z]))
    with pytest.raises(DataError, match="geographic degrees"):
        list(cloud_chunks(tmp_path / "deg.npy"))


@pytest.mark.parametrize("offset", [(0.0, 0.0), (500_000.0, 5_400_000.0), (-170.0, 80.0)])
def test_metric_map_clouds_are_read(tmp_path, offset):
    """Metric clouds near the origin, in UTM, or near (-170, 80) m are read unchanged."""
    from data_tools.formats.clouds import cloud_chunks

    x, y, z = block_scene()
    path = write_las_cloud(tmp_path / "m.las", x + offset[0], y + offset[1], z, 0.001)
    xyz = np.concatenate(list(cloud_chunks(path)))
    np.testing.assert_allclose(xyz, np.column_stack([x + offset[0], y + offset[1], z]), atol=1e-3)


def test_an_empty_map_cloud_is_an_error(tmp_path):
    """Before: exit 0 with empty outputs and not a word."""
    import laspy
    from typer.testing import CliRunner

    from prc_slam.cli import app

    path = tmp_path / "empty.las"
    laspy.LasData(laspy.LasHeader(point_format=6, version="1.4")).write(path)
    res = CliRunner().invoke(app, ["mapclass", str(path), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "empty.las: the cloud holds no points" in res.output


def test_coarse_las_scale_is_warned_once(tmp_path, caplog):
    from data_tools.formats.clouds import cloud_chunks

    x, y, z = block_scene()
    path = write_las_cloud(tmp_path / "coarse.las", x, y, z, 1.0)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        list(cloud_chunks(path))
        list(cloud_chunks(path))
    assert sum("quantised to 1" in r.getMessage() for r in caplog.records) == 1


# ------------------------------------------------------------------ nuScenes bins


def test_nuscenes_five_value_bins_are_read_with_their_ring(tmp_path):
    """nuScenes ``*.pcd.bin``: x y z intensity ring. Before: read as 4 values per point (garbage
    points; 'cannot organise' blaming the sensor) whenever the size fitted 16-byte points."""
    from data_tools.formats.pcd import read_bin

    grid = spinning_grid(16, 720)
    pts = np.swapaxes(grid, 0, 1).reshape(-1, 3)  # firing order
    ring = np.tile(np.arange(16), 720).astype(np.float32)
    ok = np.isfinite(pts).all(axis=1)
    n = int(ok.sum()) // 4 * 4  # 20 n bytes: also a whole number of 16-byte points
    data = np.column_stack([pts[ok], np.full(ok.sum(), 7.0), ring[ok]]).astype(np.float32)[:n]
    data.tofile(tmp_path / "n008__LIDAR_TOP__1533151603547590.pcd.bin")
    fields = read_bin(tmp_path / "n008__LIDAR_TOP__1533151603547590.pcd.bin")
    assert set(fields) == {"x", "y", "z", "intensity", "ring"} and len(fields["x"]) == n
    np.testing.assert_array_equal(fields["ring"], data[:, 4])
    scan = SweepFolder(tmp_path)[0]
    assert scan.shape == (16, 720) and scan.meta["organize"]["method"] == "ring-field"


def test_kitti_four_value_bins_stay_four_values(tmp_path):
    from data_tools.formats.pcd import read_bin

    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.normal(0, 20, (100, 3)), rng.random(100)]).astype(np.float32)  # 100 points: 400 = 5 x 80
    pts[:, :3] = np.round(pts[:, :3])  # even whole-metre coordinates: the intensities are not whole
    pts.tofile(tmp_path / "000000.bin")
    fields = read_bin(tmp_path / "000000.bin")
    assert set(fields) == {"x", "y", "z", "intensity"} and len(fields["x"]) == 100


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
    """Before: point times 5e8 s before (or 5000 s after) the header stamp; odometry stopped at
    frame 2 ('registration impossible')."""
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


# ------------------------------------------------------------------ Ouster npz


def test_ouster_npz_with_ranges_in_metres_is_refused(ouster_files, tmp_path):
    """range_mm converted to float metres by a user: before, read as millimetres (every point
    within 0.15 m: 97.8 % ground, no warning)."""
    from data_tools.formats.ouster import read_ouster_npz

    data = dict(np.load(ouster_files[0]))
    whole_mm = dict(data, range_mm=data["range_mm"].astype(np.float64))  # floats of whole mm: fine
    np.savez(tmp_path / "mm.npz", **whole_mm)
    assert read_ouster_npz(tmp_path / "mm.npz").valid.sum() == (data["range_mm"] > 0).sum()
    np.savez(tmp_path / "m.npz", **dict(data, range_mm=data["range_mm"].astype(np.float32) / 1000))
    with pytest.raises(DataError, match="metres"):
        read_ouster_npz(tmp_path / "m.npz")


# ------------------------------------------------------------------ units


def test_sweeps_in_millimetres_are_warned(tmp_path, caplog):
    """Before: PRC (paper preset) labelled 100 % noise, no warning."""
    grid = spinning_grid(16, 720) * 1000.0
    (tmp_path / "pcd").mkdir()
    write_pcd(tmp_path / "pcd" / "000000.pcd", flat_fields(np.swapaxes(grid, 0, 1)))
    (tmp_path / "kitti" / "velodyne").mkdir(parents=True)
    pts = np.swapaxes(grid, 0, 1).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    np.column_stack([pts, np.zeros(len(pts))]).astype(np.float32).tofile(tmp_path / "kitti" / "velodyne" / "000000.bin")
    from data_tools.formats.kitti import KittiSequence

    for seq in (SweepFolder(tmp_path / "pcd"), KittiSequence(tmp_path / "kitti")):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
            seq[0]
            seq[0]
        assert sum("not in metres" in r.getMessage() for r in caplog.records) == 1


def test_sweeps_in_metres_are_not_warned(tmp_path, caplog):
    write_pcd(tmp_path / "000000.pcd", flat_fields(np.swapaxes(spinning_grid(16, 720), 0, 1)))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        SweepFolder(tmp_path)[0]
    assert not any("not in metres" in r.getMessage() for r in caplog.records)
