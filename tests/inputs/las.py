"""LAS tiles of known classes: a ground with a wall, written with a chosen scale, offsets, point format
and withheld flags."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def ground_and_wall(n: int = 6000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 40 m x 40 m ground (ASPRS 2) with a 20 m wall 8 m high (ASPRS 6): points, classes."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(0, 40, n), rng.uniform(0, 40, n), rng.normal(0, 0.02, n)])
    m = n // 3
    wall = np.column_stack([rng.uniform(10, 30, m), np.full(m, 30.0) + rng.normal(0, 0.02, m), rng.uniform(0, 8, m)])
    return np.concatenate([ground, wall]), np.concatenate([np.full(n, 2), np.full(m, 6)]).astype(np.uint8)


def write_las(
    path: Path,
    xyz: np.ndarray,
    classes: np.ndarray | None = None,
    *,
    scale: float = 0.001,
    offset: np.ndarray | None = None,
    point_format: int = 6,
    withheld: np.ndarray | None = None,
) -> Path:
    """``xyz`` (and ``classes``, ``withheld`` flags) as a LAS file on the grid of ``scale`` and ``offset``
    (default: the floor of the minimum), LAS 1.4 for point formats 6 and up, else 1.2."""
    import laspy

    version = "1.4" if point_format >= 6 else "1.2"
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(xyz.min(axis=0)) if offset is None else offset
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    if classes is not None:
        las.classification = classes
    if withheld is not None:
        las.withheld = withheld
    las.write(path)
    return path
