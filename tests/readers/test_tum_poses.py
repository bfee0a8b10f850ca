"""TUM pose files: matched to the frames by time; files that cannot place the frames are one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from tests.inputs.poses import yaw_poses


def test_tum_poses_are_matched_to_the_frames_by_time(tmp_path, caplog):
    """``mapclass SEQ --poses traj.tum`` (as ``odometry --pose-format tum`` writes it): TUM poses are matched to
    the frames by time (a trajectory of more frames, out of order), or taken in order with a warning when the
    times are on another clock."""
    import logging

    from data_tools.formats.trajectory_io import read_pose_file, write_kitti_poses, write_tum_poses

    truth = yaw_poses(8)
    times = 0.1 * np.arange(8) + 0.003
    write_kitti_poses(tmp_path / "p.kitti", truth)
    write_tum_poses(tmp_path / "p.tum", times, truth)
    np.testing.assert_allclose(read_pose_file(tmp_path / "p.kitti", times), truth, atol=1e-9)
    np.testing.assert_allclose(read_pose_file(tmp_path / "p.tum", times), truth, atol=1e-8)
    # poses for 3 of the frames, shuffled, beside poses of other times: the frames get their own
    rows = (tmp_path / "p.tum").read_text().splitlines()
    (tmp_path / "some.tum").write_text("# t x y z qx qy qz qw\n" + "\n".join([rows[5], rows[2], rows[7]]) + "\n")
    np.testing.assert_allclose(read_pose_file(tmp_path / "some.tum", times[[2, 5, 7]]), truth[[2, 5, 7]], atol=1e-8)
    write_tum_poses(tmp_path / "clock.tum", times + 1000.0, truth)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        np.testing.assert_allclose(read_pose_file(tmp_path / "clock.tum", times), truth, atol=1e-8)
    assert "clock.tum: the TUM times" in caplog.text and "file order" in caplog.text


def test_pose_files_that_cannot_place_the_frames_are_one_line_errors(tmp_path, caplog):
    import logging

    from data_tools.errors import DataError
    from data_tools.formats.trajectory_io import read_pose_file, write_kitti_poses, write_tum_poses

    truth = yaw_poses(6)
    times = 0.1 * np.arange(6)
    write_tum_poses(tmp_path / "few.tum", times[:3] + 50.0, truth[:3])  # 3 poses, another clock
    scaled = truth.copy()
    scaled[3, :3, :3] *= 1.5  # a similarity, not a rotation
    write_kitti_poses(tmp_path / "scaled.kitti", scaled)
    mirrored = truth.copy()
    mirrored[1, :3, 2] *= -1
    write_kitti_poses(tmp_path / "mirrored.kitti", mirrored)
    (tmp_path / "seven.txt").write_text("1 2 3 4 5 6 7\n")
    for name, needle in [
        ("few.tum", "3 TUM poses for 6 frames"),
        ("scaled.kitti", "pose 4 (data row): its 3x3 block is not a rotation"),
        ("mirrored.kitti", "pose 2 (data row): its 3x3 block is not a rotation"),
        ("seven.txt", "7 values per line"),
    ]:
        with pytest.raises(DataError) as err:
            read_pose_file(tmp_path / name, times)
        assert needle in str(err.value) and name in str(err.value), str(err.value)
    # quaternions of norm 2 (not unit) are normalised, with a warning
    rows = np.loadtxt(tmp_path / "few.tum")
    rows[:, 4:] *= 2
    np.savetxt(tmp_path / "q2.tum", rows)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        got = read_pose_file(tmp_path / "q2.tum")
    np.testing.assert_allclose(got, truth[:3], atol=1e-8)
    assert "3 quaternions are not unit" in caplog.text
