"""Trajectories of known shape for pose files."""

from __future__ import annotations

import numpy as np


def yaw_poses(n: int) -> np.ndarray:
    """A drive along x turning 2 deg per frame."""
    p = np.tile(np.eye(4), (n, 1, 1))
    a = np.radians(2.0) * np.arange(n)
    p[:, 0, 0], p[:, 0, 1], p[:, 1, 0], p[:, 1, 1] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a)
    p[:, 0, 3] = 0.8 * np.arange(n)
    return p
