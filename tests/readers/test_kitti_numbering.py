"""KITTI folders whose sweep numbers do not start at 0 or do not cover the pose and time files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def _kitti_folder(root: Path, numbers: list[int], n_lines: int) -> Path:
    """A KITTI layout with sweeps ``NNNNNN.bin`` for ``numbers`` and ``n_lines`` poses (pose k at
    x = k metres) and times (k x 0.1 s), an identity ``Tr``."""
    from tests.inputs.grids import spinning_grid

    (root / "velodyne").mkdir(parents=True)
    for k in numbers:
        g = spinning_grid(seed=k).reshape(-1, 3)
        g = g[np.isfinite(g).all(axis=1)]
        np.column_stack([g, np.zeros(len(g), np.float32)]).astype(np.float32).tofile(root / "velodyne" / f"{k:06d}.bin")
    poses = np.tile(np.eye(4)[:3].ravel(), (n_lines, 1))
    poses[:, 3] = np.arange(n_lines)
    np.savetxt(root / "poses.txt", poses)
    np.savetxt(root / "times.txt", np.arange(n_lines) * 0.1)
    (root / "calib.txt").write_text("Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    return root


def test_kitti_sweeps_numbered_from_10_take_their_own_poses_and_times(tmp_path):
    """Sweeps 10, 11, 13, 14 beside the sequence's full ``poses.txt`` / ``times.txt`` take lines 10, 11, 13, 14
    (their own ground truth), not lines 1-4."""
    from data_tools.formats.kitti import KittiSequence

    seq = KittiSequence(_kitti_folder(tmp_path, [10, 11, 13, 14], 16))
    np.testing.assert_allclose(seq.poses[:, 0, 3], [10, 11, 13, 14])
    np.testing.assert_allclose(seq.times, [1.0, 1.1, 1.3, 1.4])
    scan = seq[2]
    assert scan.name == "000013"
    assert scan.gt_pose[0, 3] == pytest.approx(13.0) and scan.meta["frame_time"] == pytest.approx(1.3)


def test_kitti_lines_for_exactly_the_sweeps_present_stay_in_order(tmp_path):
    from data_tools.formats.kitti import KittiSequence

    seq = KittiSequence(_kitti_folder(tmp_path, [10, 11, 13, 14], 4))
    np.testing.assert_allclose(seq.poses[:, 0, 3], [0, 1, 2, 3])
    seq = KittiSequence(_kitti_folder(tmp_path / "b", [0, 1, 2], 16))  # KITTI's own: the first lines
    np.testing.assert_allclose(seq.poses[:, 0, 3], [0, 1, 2])


def test_kitti_sweep_numbers_beyond_the_pose_file_are_an_error(tmp_path):
    from data_tools import DataError
    from data_tools.formats.kitti import KittiSequence

    with pytest.raises(DataError, match=r"times.txt: 6 times for scans numbered 000010..000014"):
        KittiSequence(_kitti_folder(tmp_path, [10, 11, 13, 14], 6))
