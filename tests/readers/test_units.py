"""Units of the coordinates: Ouster ranges in metres are refused, sweeps in millimetres are warned,
sweeps in metres are not.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from data_tools import DataError
from data_tools.formats.pcd import SweepFolder, write_pcd
from tests.inputs.grids import flat_fields, spinning_grid


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


def test_sweeps_in_millimetres_are_warned(tmp_path, caplog):
    """Sweeps in millimetres are warned (PRC's paper preset would label every point noise)."""
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
