"""Which axis of an organised cloud holds the scan lines: rows of spinning and solid-state grids,
clouds written one firing per row (PCD and ROS), and Livox's ``line`` field, which is not a ring.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data_tools import DataError
from data_tools.formats.pcd import SweepFolder, rows_are_scan_lines, write_pcd
from data_tools.formats.rosbag import cloud_from_records, cloud_to_scan
from data_tools.organize import Organizer
from tests.inputs.grids import flat_fields, spinning_grid


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
    """An organised PCD written one firing per row (``HEIGHT`` = 720 columns, ``WIDTH`` = 16 beams) is organised
    into 16 rings of 720 columns, with a warning about the row order."""
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
    """Livox's ``line`` field (the laser of a non-repetitive pattern) is not taken as a ring: a rosette of
    20,000 points is not organised as 6 rings of ~200,000 columns."""
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
