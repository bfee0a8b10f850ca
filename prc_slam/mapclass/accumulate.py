"""The registered map of a run: every frame's points moved into the world frame at their own
acquisition time (poses interpolated between frame poses: linear in translation, slerp in
rotation), with whatever per-point attributes the caller carries along.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from prc_slam.scan import Scan


def to_world(
    points: np.ndarray, times: np.ndarray | None, frame_times: np.ndarray, frame_poses: np.ndarray
) -> np.ndarray:
    """Sensor-frame points to the world frame at their own time.

    Parameters
    ----------
    points : float (N, 3)
    times : float (N,) or None
        Acquisition times (s); None moves every point with the first pose.
    frame_times : float (F,)
        Increasing times of ``frame_poses``.
    frame_poses : float (F, 4, 4)
        Sensor poses in the world; times outside the range take the nearest pose.
    """
    pts = np.asarray(points, dtype=np.float64)
    frame_poses = np.asarray(frame_poses, dtype=np.float64)
    if times is None or len(frame_poses) == 1:
        return pts @ frame_poses[0, :3, :3].T + frame_poses[0, :3, 3]
    t = np.clip(np.asarray(times, dtype=np.float64), frame_times[0], frame_times[-1])
    rot = Slerp(frame_times, Rotation.from_matrix(frame_poses[:, :3, :3]))(t)
    trans = np.column_stack([np.interp(t, frame_times, frame_poses[:, k, 3]) for k in range(3)])
    return rot.apply(pts) + trans


@dataclass
class MapCloud:
    """An accumulated map: world points and, per point, its frame and optional attributes."""

    points: np.ndarray
    frame: np.ndarray
    attributes: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)


def accumulate(
    frames: Iterable[tuple[int, Scan, dict[str, np.ndarray]]],
    poses: np.ndarray,
    frame_times: np.ndarray,
) -> MapCloud:
    """Accumulate frames into one world-frame cloud.

    Parameters
    ----------
    frames : iterable of (index, Scan, attributes)
        The frames to use (any subset, in any order), each with its index into ``poses`` and
        per-point arrays to carry along (e.g. ``{"prc": labels}``).
    poses : float (F, 4, 4)
        Pose of every frame of the sequence at its ``frame_times`` (ground truth or an
        odometry's); each point takes the pose interpolated at its own time between the frame's
        neighbours.
    frame_times : float (F,)
    """
    chunks, ids, attrs = [], [], {}
    for i, scan, extra in frames:
        if not 0 <= i < len(poses):
            raise ValueError(f"{scan.source}: frame {i} has no pose ({len(poses)} poses)")
        pts, times = scan.points(), scan.point_times()
        lo, hi = (max(i - 1, 0), min(i + 2, len(poses))) if times is not None else (i, i + 1)
        chunks.append(to_world(pts, times, frame_times[lo:hi], poses[lo:hi]))
        ids.append(np.full(len(pts), i, dtype=np.int32))
        for k, v in extra.items():
            if len(v) != len(pts):
                raise ValueError(f"{scan.source}: attribute {k!r} has {len(v)} values for {len(pts)} points")
            attrs.setdefault(k, []).append(np.asarray(v))
    if not chunks:
        return MapCloud(np.zeros((0, 3)), np.zeros(0, np.int32), {})
    return MapCloud(np.concatenate(chunks), np.concatenate(ids), {k: np.concatenate(v) for k, v in attrs.items()})
