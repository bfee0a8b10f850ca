"""Label-driven point filtering before registration (PRC paper, Sec. V: remove noise and
downsample the ground before SLAM).

Noise is dropped; ground is thinned to one point per cell of a horizontal grid (sensor frame)
rather than removed, so it still holds height and tilt; everything else is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from prc_slam import labels as L


class FilterConfig(BaseModel):
    """What reaches the registration. Defaults measured on simulated and KITTI drives (README)."""

    model_config = ConfigDict(extra="forbid")

    drop: list[int] = Field(default_factory=lambda: [L.NOISE], description="codes removed entirely")
    thin: list[int] = Field(default_factory=lambda: [L.GROUND], description="codes thinned on a grid")
    cell: float = Field(1.0, gt=0, description="grid cell (m) of the thinned classes; one point per cell")
    keep_one_sided: bool = Field(
        True, description="keep noise points that meet one of the two support conditions of eq. (4) (thin poles)"
    )


@dataclass
class FilterResult:
    """Mask of the kept points and the counts per class (in and kept)."""

    keep: np.ndarray
    counts_in: dict[str, int]
    counts_kept: dict[str, int]

    @property
    def n_in(self) -> int:
        return len(self.keep)

    @property
    def n_kept(self) -> int:
        return int(self.keep.sum())


@njit(cache=True, nogil=True)
def _filter_kernel(points, labels, drop, thin, cell, spare):
    """One pass: drop by class (except ``spare`` points), keep the first point (input order)
    of every occupied grid cell for the thinned classes (open-addressing hash of the cell,
    O(n)), count per class."""
    n = points.shape[0]
    size = 1
    while size < 2 * n + 2:
        size *= 2
    keys_x = np.empty(size, np.int64)
    keys_y = np.empty(size, np.int64)
    used = np.zeros(size, np.bool_)
    keep = np.zeros(n, np.bool_)
    n_in = np.zeros(256, np.int64)
    n_kept = np.zeros(256, np.int64)
    for i in range(n):
        c = labels[i]
        n_in[c] += 1
        if drop[c] and not spare[i]:
            continue
        if thin[c]:
            cx = np.int64(np.floor(points[i, 0] / cell))
            cy = np.int64(np.floor(points[i, 1] / cell))
            h = ((cx * 73856093) ^ (cy * 19349663)) & (size - 1)
            while used[h] and not (keys_x[h] == cx and keys_y[h] == cy):
                h = (h + 1) & (size - 1)
            if used[h]:
                continue
            used[h] = True
            keys_x[h] = cx
            keys_y[h] = cy
        keep[i] = True
        n_kept[c] += 1
    return keep, n_in, n_kept


def filter_points(
    points: np.ndarray, labels: np.ndarray, config: FilterConfig, one_sided: np.ndarray | None = None
) -> FilterResult:
    """Choose the points that go to registration.

    Parameters
    ----------
    points : float (N, 3)
        Sensor-frame coordinates (the grid of the thinned classes is laid in x-y).
    labels : uint8 (N,)
        One code per point.
    config : FilterConfig
    one_sided : bool (N,), optional
        PRC's one-sided noise points; with ``config.keep_one_sided`` they are not dropped
        (PRC removes thin poles and trunks, which hold an odometry's along-track position).

    Returns
    -------
    FilterResult
        ``keep[i]`` says whether point ``i`` is kept; inputs are not modified.
    """
    points = np.asarray(points)
    labels = np.asarray(labels, dtype=np.uint8)
    if points.ndim != 2 or points.shape[1] != 3 or labels.shape != (len(points),):
        raise ValueError(f"points {points.shape} and labels {labels.shape} do not match")
    drop = np.zeros(256, dtype=bool)
    drop[config.drop] = True
    thin = np.zeros(256, dtype=bool)
    thin[config.thin] = True
    spare = np.zeros(len(points), dtype=bool)
    if config.keep_one_sided and one_sided is not None:
        if np.shape(one_sided) != (len(points),):
            raise ValueError(f"one_sided has shape {np.shape(one_sided)} for {len(points)} points")
        spare = np.asarray(one_sided, dtype=bool)
    keep, n_in, n_kept = _filter_kernel(points, labels, drop, thin, float(config.cell), spare)
    present = np.flatnonzero(n_in)
    counts_in = {L.CODE_TO_NAME.get(int(c), f"code_{c}"): int(n_in[c]) for c in present}
    counts_kept = {L.CODE_TO_NAME.get(int(c), f"code_{c}"): int(n_kept[c]) for c in present}
    return FilterResult(keep, counts_in, counts_kept)
