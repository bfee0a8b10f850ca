"""ATE, RPE and the KITTI odometry error on constructed trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from data_tools.formats.kitti import read_kitti_poses
from data_tools.formats.trajectory_io import read_tum_poses, write_kitti_poses, write_tum_poses
from prc_slam.evaluation.metrics import ate_rmse, kitti_errors, rpe


def straight(n: int, step: float = 1.0) -> np.ndarray:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * step
    return poses


def yaw(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def test_ate_is_invariant_to_a_rigid_offset_and_sees_noise():
    ref = straight(50)
    moved = yaw(0.3) @ ref
    moved[:, :3, 3] += [5, -2, 1]
    assert ate_rmse(moved, ref) == pytest.approx(0.0, abs=1e-9)
    noisy = ref.copy()
    noisy[::2, 1, 3] += 0.1
    noisy[1::2, 1, 3] -= 0.1
    assert ate_rmse(noisy, ref) == pytest.approx(0.1, rel=2e-3)  # alignment absorbs a little


def test_rpe_hand_computed():
    ref = straight(4)
    est = straight(4)
    est[2:, 0, 3] += 0.5  # one step 0.5 m too long
    np.testing.assert_allclose(rpe(est, ref), [0.0, 0.5, 0.0])


def test_kitti_error_of_a_scaled_trajectory():
    ref = straight(300, 1.0)  # 299 m
    est = straight(300, 1.02)  # 2 % too long
    t, r = kitti_errors(est, ref)
    assert t == pytest.approx(2.0, rel=1e-3)
    assert r == pytest.approx(0.0, abs=1e-9)
    assert kitti_errors(straight(50), straight(50)) == (None, None)  # shorter than 100 m


def test_kitti_error_of_a_constant_yaw_drift():
    n = 201
    ref = straight(n)
    est = np.array([ref[0]] * n)
    for i in range(1, n):  # 0.001 rad of yaw per metre, integrated
        est[i] = est[i - 1] @ yaw(0.001) @ (np.linalg.inv(ref[i - 1]) @ ref[i])
    _, r = kitti_errors(est, ref, lengths=(100,))
    assert r == pytest.approx(np.degrees(0.001), rel=0.02)


def test_kitti_and_tum_files_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    poses = np.array([yaw(a) for a in rng.uniform(-3, 3, 20)])
    poses[:, :3, 3] = rng.normal(size=(20, 3))
    write_kitti_poses(tmp_path / "k.txt", poses)
    np.testing.assert_allclose(read_kitti_poses(tmp_path / "k.txt"), poses, atol=1e-8)
    write_tum_poses(tmp_path / "t.txt", np.arange(20) * 0.1, poses)
    t, back = read_tum_poses(tmp_path / "t.txt")
    np.testing.assert_allclose(back, poses, atol=1e-7)
    np.testing.assert_allclose(t, np.arange(20) * 0.1)


def test_ate_and_rpe_agree_with_evo(tmp_path):
    from evo.core import metrics
    from evo.tools import file_interface

    rng = np.random.default_rng(1)
    ref = straight(120, 0.8)
    for i in range(1, 120):  # a curving reference
        ref[i] = ref[i - 1] @ yaw(0.02) @ (np.linalg.inv(straight(2, 0.8)[0]) @ straight(2, 0.8)[1])
    est = ref.copy()
    est[:, :3, 3] += np.cumsum(rng.normal(0, 0.02, (120, 3)), axis=0)  # drift
    est = yaw(0.4) @ est  # and a different start frame
    write_kitti_poses(tmp_path / "ref.txt", ref)
    write_kitti_poses(tmp_path / "est.txt", est)
    traj_ref = file_interface.read_kitti_poses_file(str(tmp_path / "ref.txt"))
    traj_est = file_interface.read_kitti_poses_file(str(tmp_path / "est.txt"))
    traj_est.align(traj_ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((traj_ref, traj_est))
    assert ate_rmse(est, ref) == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse), rel=1e-6)
    rel = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames, all_pairs=False)
    rel.process_data(
        (
            file_interface.read_kitti_poses_file(str(tmp_path / "ref.txt")),
            file_interface.read_kitti_poses_file(str(tmp_path / "est.txt")),
        )
    )
    np.testing.assert_allclose(rpe(est, ref), rel.error, rtol=1e-6, atol=1e-9)
