"""KITTI folders whose sweep numbers do not start at 0 or do not cover the pose and time files."""

from __future__ import annotations

import numpy as np
import pytest

from tests.inputs.kitti import kitti_folder


def test_kitti_sweeps_numbered_from_10_take_their_own_poses_and_times(tmp_path):
    """Sweeps 10, 11, 13, 14 beside the sequence's full ``poses.txt`` / ``times.txt`` take lines 10, 11, 13, 14
    (their own ground truth), not lines 1-4."""
    from data_tools.formats.kitti import KittiSequence

    seq = KittiSequence(kitti_folder(tmp_path, [10, 11, 13, 14], 16))
    np.testing.assert_allclose(seq.poses[:, 0, 3], [10, 11, 13, 14])
    np.testing.assert_allclose(seq.times, [1.0, 1.1, 1.3, 1.4])
    scan = seq[2]
    assert scan.name == "000013"
    assert scan.gt_pose[0, 3] == pytest.approx(13.0) and scan.meta["frame_time"] == pytest.approx(1.3)


def test_kitti_lines_for_exactly_the_sweeps_present_stay_in_order(tmp_path):
    from data_tools.formats.kitti import KittiSequence

    seq = KittiSequence(kitti_folder(tmp_path, [10, 11, 13, 14], 4))
    np.testing.assert_allclose(seq.poses[:, 0, 3], [0, 1, 2, 3])
    seq = KittiSequence(kitti_folder(tmp_path / "b", [0, 1, 2], 16))  # KITTI's own: the first lines
    np.testing.assert_allclose(seq.poses[:, 0, 3], [0, 1, 2])


def test_kitti_sweep_numbers_beyond_the_pose_file_are_an_error(tmp_path):
    from data_tools import DataError
    from data_tools.formats.kitti import KittiSequence

    with pytest.raises(DataError, match=r"times.txt: 6 times for scans numbered 000010..000014"):
        KittiSequence(kitti_folder(tmp_path, [10, 11, 13, 14], 6))
