"""Pose files: poses whose z is not up are warned."""

from __future__ import annotations

import logging

import numpy as np

from tests.inputs.kitti import kitti_folder


def test_poses_whose_z_is_not_up_are_warned(tmp_path, caplog):
    """Poses whose z is not up (KITTI's ``poses.txt`` in camera 0's frame, where the car drives along z) are
    warned: stacked that way, the sweeps lie 0.86 m above each other and the map classes go wrong."""
    from data_tools.formats.kitti import KittiSequence
    from prc_slam.jobs.mapclass import map_from_dataset, warn_unless_z_up

    def poses(axis: int, step: float, n: int = 6) -> np.ndarray:
        p = np.tile(np.eye(4), (n, 1, 1))
        p[:, axis, 3] = np.arange(n) * step
        return p

    with caplog.at_level(logging.WARNING, logger="prc_slam.mapclass"):
        assert warn_unless_z_up(poses(2, 0.86), "camera.txt")  # KITTI camera 0: forward is z
        assert not warn_unless_z_up(poses(0, 0.86), "lidar.txt")  # forward is x
        assert not warn_unless_z_up(poses(2, 0.1), "short.txt")  # 0.5 m of path: a lift, not a drive
        assert not warn_unless_z_up(poses(0, 0.0), "still.txt")
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["camera.txt"]
    caplog.clear()
    root = kitti_folder(tmp_path / "seq", [0, 1, 2, 3], 4)
    np.savetxt(tmp_path / "cam.txt", poses(2, 0.86, 4)[:, :3, :].reshape(4, 12))
    with caplog.at_level(logging.WARNING, logger="prc_slam.mapclass"):
        map_from_dataset(KittiSequence(root), 4, 1, tmp_path / "cam.txt")
    assert "cam.txt: the poses climb 2.6 m and move 0.0 m horizontally" in caplog.text
