"""KITTI and TUM trajectory files (readable by evo)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from data_tools.errors import DataError
from data_tools.textfiles import read_numeric_table

log = logging.getLogger("prc_slam.readers")


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file (one row-major 3x4 matrix per line) as ``float64[n, 4, 4]``; errors
    name the file and the (1-based) line."""
    data = read_numeric_table(path, 12, "KITTI poses: 12 values per line, a row-major 3x4 matrix")
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    poses[:, :3, :] = data.reshape(-1, 3, 4)
    return poses


def read_times(path: str | Path) -> np.ndarray:
    """Read ``times.txt`` (one time in seconds per line), checking that they increase; errors name
    the file and the (1-based) line."""
    t = read_numeric_table(path, 1, "one time in seconds per line")[:, 0]
    if (np.diff(t) <= 0).any():
        # data rows, not file lines, when the file has blank or comment lines; the same here
        raise DataError(f"{path}: line {int(np.argmax(np.diff(t) <= 0)) + 2}: times are not strictly increasing")
    return t


#: a step between frame times this many times the median step is a gap (frames dropped)
GAP_FACTOR = 3.0


def warn_time_gaps(times: np.ndarray, source: str | Path) -> int:
    """Warn once when frame times jump by more than :data:`GAP_FACTOR` times their median step
    (frames missing: odometry's constant-velocity prediction is then off by the distance driven
    in the gap); returns the number of such gaps."""
    t = np.asarray(times, dtype=np.float64)
    if len(t) < 4:
        return 0
    step = np.diff(t)
    median = float(np.median(step))
    if not median > 0:
        return 0
    gaps = np.flatnonzero(step > GAP_FACTOR * median)
    if len(gaps):
        k = int(gaps[np.argmax(step[gaps])])
        log.warning(
            "%s: %d gap%s in the frame times, the largest %.3g s between frames %d and %d (%.1f x the median "
            "step of %.3g s): frames missing? Odometry predicts the motion from the previous step",
            source,
            len(gaps),
            "s" if len(gaps) > 1 else "",
            step[k],
            k,
            k + 1,
            step[k] / median,
            median,
        )
    return len(gaps)


def write_kitti_poses(path: str | Path, poses: np.ndarray) -> None:
    """One row-major 3x4 matrix per line."""
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise DataError(f"{path}: poses must be (n, 4, 4), got {poses.shape}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, poses[:, :3, :].reshape(len(poses), 12), fmt="%.9e")


def _quat_from_matrix(rot: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, w)`` of rotation matrices ``(n, 3, 3)`` (w >= 0)."""
    m = rot
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    q = np.empty((len(m), 4))
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)
    k = np.argmax(cand, axis=1)
    for case in range(4):  # four formulas, vectorised over the poses of each case
        i = k == case
        if not i.any():
            continue
        a = m[i]
        if case == 0:
            s = np.sqrt(tr[i] + 1.0) * 2
            q[i] = np.stack(
                [(a[:, 2, 1] - a[:, 1, 2]) / s, (a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 1, 0] - a[:, 0, 1]) / s, 0.25 * s],
                1,
            )
        elif case == 1:
            s = np.sqrt(1.0 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2]) * 2
            q[i] = np.stack(
                [0.25 * s, (a[:, 0, 1] + a[:, 1, 0]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s, (a[:, 2, 1] - a[:, 1, 2]) / s],
                1,
            )
        elif case == 2:
            s = np.sqrt(1.0 + a[:, 1, 1] - a[:, 0, 0] - a[:, 2, 2]) * 2
            q[i] = np.stack(
                [(a[:, 0, 1] + a[:, 1, 0]) / s, 0.25 * s, (a[:, 1, 2] + a[:, 2, 1]) / s, (a[:, 0, 2] - a[:, 2, 0]) / s],
                1,
            )
        else:
            s = np.sqrt(1.0 + a[:, 2, 2] - a[:, 0, 0] - a[:, 1, 1]) * 2
            q[i] = np.stack(
                [(a[:, 0, 2] + a[:, 2, 0]) / s, (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s, (a[:, 1, 0] - a[:, 0, 1]) / s],
                1,
            )
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _matrix_from_quat(q: np.ndarray) -> np.ndarray:
    x, y, z, w = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def write_tum_poses(path: str | Path, times: np.ndarray, poses: np.ndarray) -> None:
    """``t x y z qx qy qz qw`` per line."""
    poses = np.asarray(poses, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    if len(times) != len(poses):
        raise DataError(f"{path}: {len(times)} times for {len(poses)} poses")
    q = _quat_from_matrix(poses[:, :3, :3])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.column_stack([times, poses[:, :3, 3], q]), fmt="%.9f")


def read_tum_poses(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Times ``(n,)`` and poses ``(n, 4, 4)`` of a TUM file."""
    data = read_numeric_table(path, 8, "TUM poses (t x y z qx qy qz qw)")
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    if len(data):
        poses[:, :3, :3] = _matrix_from_quat(data[:, 4:8])
        poses[:, :3, 3] = data[:, 1:4]
    return data[:, 0] if len(data) else np.zeros(0), poses


__all__ = [
    "read_kitti_poses",
    "read_times",
    "read_tum_poses",
    "warn_time_gaps",
    "write_kitti_poses",
    "write_tum_poses",
]
