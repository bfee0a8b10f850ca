"""Binary sweep files: nuScenes five-value bins are read with their ring, KITTI four-value bins stay
four values.
"""

from __future__ import annotations

import numpy as np

from data_tools.formats.pcd import SweepFolder
from tests.inputs.grids import spinning_grid


def test_nuscenes_five_value_bins_are_read_with_their_ring(tmp_path):
    """nuScenes ``*.pcd.bin`` (x y z intensity ring) is read as five values per point with its ring, even when
    the file size would also fit 16-byte points."""
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
