"""KITTI and TUM trajectory files (readable by evo)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from data_tools.errors import DataError
from data_tools.formats.textfiles import read_numeric_table

log = logging.getLogger("prc_slam.readers")


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file (one row-major 3x4 matrix per line) as ``float64[n, 4, 4]``; errors
    name the file and the (1-based) line."""
    data = read_numeric_table(path, 12, "KITTI poses: 12 values per line, a row-major 3x4 matrix")
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    poses[:, :3, :] = data.reshape(-1, 3, 4)
    check_rotations(path, poses)
    return poses


#: a pose's 3x3 block may differ from a rotation (R R^T = I, det R = 1) by this much (rounding)
ROTATION_TOLERANCE = 1e-2


def check_rotations(path: str | Path, poses: np.ndarray) -> None:
    """Raise :class:`DataError` naming the first pose (data row) whose rotation block is not a
    rotation: a scaled, sheared or mirrored block (a similarity from monocular SLAM, columns in
    another order) would place every point of the sweep silently wrong."""
    rot = np.asarray(poses, np.float64)[:, :3, :3]
    if not len(rot):
        return
    err = np.abs(rot @ np.swapaxes(rot, 1, 2) - np.eye(3)).max(axis=(1, 2))
    bad = (err > ROTATION_TOLERANCE) | (np.linalg.det(rot) < 0)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(
            f"{path}: pose {i + 1} (data row): its 3x3 block is not a rotation (|R R^T - I| = {err[i]:.3g}, "
            f"det {np.linalg.det(rot[i]):.3g}); expected KITTI poses (row-major [R | t])"
        )


#: frame times and TUM pose times that differ by less than this (s) are the same instant
TUM_TIME_TOLERANCE = 0.005


def read_pose_file(path: str | Path, times: np.ndarray | None = None) -> np.ndarray:
    """Poses ``(n, 4, 4)`` for the frames at ``times`` from a KITTI file (12 values per line:
    one pose per frame, in order) or a TUM file (8: ``t x y z qx qy qz qw``).

    A TUM file's poses are matched to the frames by time when every frame time has a pose within
    :data:`TUM_TIME_TOLERANCE` (a trajectory of some of the frames, or of more); otherwise, when it
    holds one pose per frame, in order (a warning says the times did not match: another clock);
    otherwise a :class:`DataError`."""
    path = Path(path)
    head = read_numeric_table(path, None, "KITTI (12 values per line) or TUM (8) poses")
    width = head.shape[1] if head.ndim == 2 and len(head) else 12
    if width == 12:
        return read_kitti_poses(path)
    if width != 8:
        raise DataError(f"{path}: {width} values per line: expected KITTI poses (12 per line) or TUM poses (8)")
    stamps, poses = read_tum_poses(path)
    if times is None or not len(times):
        return poses
    times = np.asarray(times, np.float64)
    order = np.argsort(stamps, kind="stable")
    j = np.clip(np.searchsorted(stamps[order], times), 1, max(len(stamps) - 1, 1))
    near = np.where(
        np.abs(stamps[order][j - 1] - times) <= np.abs(stamps[order][np.minimum(j, len(stamps) - 1)] - times),
        j - 1,
        np.minimum(j, len(stamps) - 1),
    )
    if len(stamps) and (np.abs(stamps[order][near] - times) <= TUM_TIME_TOLERANCE).all():
        return poses[order][near]
    if len(poses) >= len(times):
        log.warning(
            "%s: the TUM times (%.3f..%.3f s) are not the frame times (%.3f..%.3f s): poses taken in file order, "
            "one per frame",
            path,
            stamps.min(),
            stamps.max(),
            times.min(),
            times.max(),
        )
        return poses
    raise DataError(
        f"{path}: {len(poses)} TUM poses for {len(times)} frames, at times not the frames' ({stamps.min():.3f}.."
        f"{stamps.max():.3f} s against {times.min():.3f}..{times.max():.3f} s)"
    )


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
            "step of %.3g s): frames missing? Odometry stretches its constant-velocity prediction over the gap",
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
    norms = np.linalg.norm(data[:, 4:8], axis=1) if len(data) else np.ones(0)
    if (norms < 1e-6).any():
        raise DataError(f"{path}: pose {int(np.argmax(norms < 1e-6)) + 1} (data row): zero quaternion")
    if (np.abs(norms - 1) > ROTATION_TOLERANCE).any():
        log.warning(
            "%s: %d quaternions are not unit (norm %.3g..%.3g): normalised",
            path,
            int((np.abs(norms - 1) > ROTATION_TOLERANCE).sum()),
            norms.min(),
            norms.max(),
        )
    if len(data):
        poses[:, :3, :3] = _matrix_from_quat(data[:, 4:8])
        poses[:, :3, 3] = data[:, 1:4]
    return data[:, 0] if len(data) else np.zeros(0), poses


__all__ = [
    "check_rotations",
    "read_kitti_poses",
    "read_pose_file",
    "read_times",
    "read_tum_poses",
    "warn_time_gaps",
    "write_kitti_poses",
    "write_tum_poses",
]
