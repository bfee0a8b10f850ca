"""The class-group voxel map of the class-aware registration: KISS-ICP's voxel map rules
(``VoxelHashMap``: points per voxel, minimum spacing, far points dropped) with the class group as
part of the voxel key, in numpy arrays that the numba ICP searches directly."""

from __future__ import annotations

import numpy as np
from numba import njit

from prc_slam.util.voxels import _rehash, _slot


@njit(cache=True, nogil=True)
def _add_points(table, coords, count, pts, n, points, groups, inv_voxel, m, min_d2):
    """KISS-ICP's ``VoxelHashMap::AddPoints`` with the group as part of the voxel key: a point
    joins its (voxel, group) unless the voxel holds ``m`` points or one closer than the map
    resolution. ``table`` must have room for every point to open a voxel. Returns the new
    voxel count."""
    mask = table.shape[0] - 1
    for i in range(points.shape[0]):
        x = np.int64(np.floor(points[i, 0] * inv_voxel))
        y = np.int64(np.floor(points[i, 1] * inv_voxel))
        z = np.int64(np.floor(points[i, 2] * inv_voxel)) * 8 + groups[i]
        h = _slot(x, y, z, mask)
        while True:
            v = table[h]
            if v < 0:
                table[h] = n
                coords[n, 0], coords[n, 1], coords[n, 2] = x, y, z
                pts[n * m] = points[i]
                count[n] = 1
                n += 1
                break
            if coords[v, 0] == x and coords[v, 1] == y and coords[v, 2] == z:
                c = count[v]
                if c < m:
                    close = False
                    for k in range(v * m, v * m + c):
                        d2 = (
                            (pts[k, 0] - points[i, 0]) ** 2
                            + (pts[k, 1] - points[i, 1]) ** 2
                            + (pts[k, 2] - points[i, 2]) ** 2
                        )
                        if d2 < min_d2:
                            close = True
                            break
                    if not close:
                        pts[v * m + c] = points[i]
                        count[v] = c + 1
                break
            h = (h + 1) & mask
    return n


@njit(cache=True, nogil=True)
def _drop_far(count, pts, n, m, origin, max_d2):
    """Empty the voxels whose first point lies farther than ``sqrt(max_d2)`` from ``origin``
    (KISS-ICP's ``RemovePointsFarFromLocation``); returns how many voxels are empty."""
    empty = 0
    for v in range(n):
        if count[v] > 0:
            k = v * m
            d2 = (pts[k, 0] - origin[0]) ** 2 + (pts[k, 1] - origin[1]) ** 2 + (pts[k, 2] - origin[2]) ** 2
            if d2 > max_d2:
                count[v] = 0
        if count[v] == 0:
            empty += 1
    return empty


class GroupVoxelMap:
    """KISS-ICP's voxel hash map (voxel size, at most ``max_points_per_voxel`` per voxel, no two
    points closer than ``voxel / sqrt(max_points_per_voxel)``, voxels beyond ``max_distance``
    dropped) keyed by (voxel, class group), held in numpy arrays so that the numba ICP searches
    it in place. ``_VoxelHashMap`` cannot carry labels, and copying four of its clouds out and
    indexing them every frame cost more than the registration."""

    def __init__(self, voxel: float, max_distance: float, max_points_per_voxel: int) -> None:
        self.voxel, self.max_distance, self.m = float(voxel), float(max_distance), int(max_points_per_voxel)
        self.min_d2 = (self.voxel / np.sqrt(self.m)) ** 2
        self.n = 0
        self._allocate(1024)

    def _allocate(self, capacity: int) -> None:
        self.coords = np.empty((capacity, 3), np.int64)
        self.count = np.zeros(capacity, np.int64)
        self.pts = np.empty((capacity * self.m, 3))
        self.table = np.full(2 * capacity, -1, np.int64)  # a power of two, at most half full

    def _resize(self, capacity: int) -> None:
        """Keep the non-empty voxels in arrays of ``capacity`` voxels and rebuild the hash."""
        alive = np.flatnonzero(self.count[: self.n] > 0)
        coords, count = self.coords[alive], self.count[alive]
        pts = self.pts.reshape(-1, self.m, 3)[alive]
        self._allocate(capacity)
        self.n = len(alive)
        self.coords[: self.n], self.count[: self.n] = coords, count
        self.pts.reshape(-1, self.m, 3)[: self.n] = pts
        self.table = _rehash(self.coords, self.n, len(self.table))

    def update(self, points: np.ndarray, groups: np.ndarray, pose: np.ndarray) -> None:
        """Add sensor-frame ``points`` of ``groups`` at ``pose`` and drop far voxels."""
        world = np.ascontiguousarray(points @ pose[:3, :3].T + pose[:3, 3])
        capacity = len(self.count)
        if self.n + len(world) > capacity:
            self._resize(1 << int(np.ceil(np.log2(self.n + len(world) + 1))))
        self.n = _add_points(
            self.table, self.coords, self.count, self.pts, self.n, world, np.asarray(groups, np.int64),
            1.0 / self.voxel, self.m, self.min_d2,
        )  # fmt: skip
        empty = _drop_far(self.count, self.pts, self.n, self.m, pose[:3, 3].copy(), self.max_distance**2)
        if empty > self.n // 2 and self.n > 1024:
            self._resize(len(self.count))

    def index(self) -> tuple[np.ndarray, ...]:
        """``(table, coords, first, count, points)`` for :func:`icp`."""
        return self.table, self.coords, np.arange(self.n) * self.m, self.count[: self.n], self.pts

    def point_cloud(self) -> tuple[np.ndarray, np.ndarray]:
        """All map points (world frame) and their groups."""
        keep = np.arange(self.m)[None, :] < self.count[: self.n, None]
        pts = self.pts[: self.n * self.m].reshape(self.n, self.m, 3)[keep]
        groups = np.repeat(
            self.coords[: self.n, 2] - np.floor_divide(self.coords[: self.n, 2], 8) * 8, self.count[: self.n]
        )
        return pts, groups
