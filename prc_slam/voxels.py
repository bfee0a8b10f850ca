"""Sparse voxel grids, shared by the map classification (paper 004, Sec. 3.1, 3.3, 3.4, 4.2,
4.4) and the class-aware registration's correspondence search.

A grid is an open-addressing hash from integer voxel coordinates to a dense voxel index, built
in one O(N) pass (no sort). Everything is numba; callers get arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _slot(x, y, z, mask):
    return ((x * 73856093) ^ (y * 19349663) ^ (z * 83492791)) & mask


@njit(cache=True, nogil=True)
def _rehash(coords, nv, size):
    mask = size - 1
    table = np.full(size, -1, np.int64)
    for v in range(nv):
        h = _slot(coords[v, 0], coords[v, 1], coords[v, 2], mask)
        while table[h] >= 0:
            h = (h + 1) & mask
        table[h] = v
    return table


@njit(cache=True, nogil=True)
def _build(points, inv_size):
    """Voxel index per point; the table doubles whenever it is half full."""
    n = points.shape[0]
    size = 1024
    table = np.full(size, -1, np.int64)
    coords = np.empty((max(n, 1), 3), np.int64)
    voxel = np.empty(n, np.int64)
    nv = 0
    for i in range(n):
        x = np.int64(np.floor(points[i, 0] * inv_size))
        y = np.int64(np.floor(points[i, 1] * inv_size))
        z = np.int64(np.floor(points[i, 2] * inv_size))
        mask = size - 1
        h = _slot(x, y, z, mask)
        while True:
            v = table[h]
            if v < 0:
                table[h] = nv
                coords[nv, 0], coords[nv, 1], coords[nv, 2] = x, y, z
                voxel[i] = nv
                nv += 1
                if 2 * nv > size:
                    size *= 2
                    table = _rehash(coords, nv, size)
                break
            if coords[v, 0] == x and coords[v, 1] == y and coords[v, 2] == z:
                voxel[i] = v
                break
            h = (h + 1) & mask
    return voxel, coords[:nv].copy(), table


@njit(cache=True, nogil=True, inline="always")
def find(table, coords, x, y, z):
    """Index of voxel ``(x, y, z)`` or -1."""
    mask = table.shape[0] - 1
    h = _slot(x, y, z, mask)
    while True:
        v = table[h]
        if v < 0:
            return -1
        if coords[v, 0] == x and coords[v, 1] == y and coords[v, 2] == z:
            return v
        h = (h + 1) & mask


@njit(cache=True, nogil=True)
def _neighbours(table, coords, radius):
    """``(V, (2r+1)^3)`` indices of the voxels around each voxel (itself included), -1 if empty."""
    nv = coords.shape[0]
    w = 2 * radius + 1
    out = np.full((nv, w * w * w), -1, np.int64)
    for v in range(nv):
        k = 0
        for dx in range(-radius, radius + 1):
            for dy in range(-radius, radius + 1):
                for dz in range(-radius, radius + 1):
                    out[v, k] = find(table, coords, coords[v, 0] + dx, coords[v, 1] + dy, coords[v, 2] + dz)
                    k += 1
    return out


@njit(cache=True, nogil=True)
def _neighbourhood_sum(table, coords, values, radius):
    nv, m = values.shape
    out = np.zeros((nv, m))
    for v in range(nv):
        for dx in range(-radius, radius + 1):
            for dy in range(-radius, radius + 1):
                for dz in range(-radius, radius + 1):
                    u = find(table, coords, coords[v, 0] + dx, coords[v, 1] + dy, coords[v, 2] + dz)
                    if u >= 0:
                        for j in range(m):
                            out[v, j] += values[u, j]
    return out


@njit(cache=True, nogil=True)
def _root(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit(cache=True, nogil=True)
def _components(table, coords):
    """26-connected components of the occupied voxels (union-find), ids 0..C-1."""
    nv = coords.shape[0]
    parent = np.arange(nv)
    for v in range(nv):
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    u = find(table, coords, coords[v, 0] + dx, coords[v, 1] + dy, coords[v, 2] + dz)
                    if u > v:
                        ra, rb = _root(parent, v), _root(parent, u)
                        if ra != rb:
                            parent[max(ra, rb)] = min(ra, rb)
    comp = np.empty(nv, np.int64)
    ids = np.full(nv, -1, np.int64)
    nc = 0
    for v in range(nv):
        r = _root(parent, v)
        if ids[r] < 0:
            ids[r] = nc
            nc += 1
        comp[v] = ids[r]
    return comp


@dataclass
class VoxelGrid:
    """Points binned into cubes of side ``size``.

    Attributes
    ----------
    voxel : int64 (N,)
        Voxel index of every point.
    coords : int64 (V, 3)
        Integer coordinates of every occupied voxel.
    counts : int64 (V,)
        Points per voxel.
    """

    size: float
    voxel: np.ndarray
    coords: np.ndarray
    table: np.ndarray
    counts: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, size: float) -> VoxelGrid:
        voxel, coords, table = _build(np.asarray(points, dtype=np.float64), 1.0 / size)
        return cls(size, voxel, coords, table, np.bincount(voxel, minlength=len(coords)))

    @property
    def n_voxels(self) -> int:
        return len(self.coords)

    def neighbours(self, radius: int = 1) -> np.ndarray:
        """Indices of the ``(2r+1)^3`` voxels around every voxel (itself included), -1 where empty."""
        return _neighbours(self.table, self.coords, radius)

    def components(self) -> np.ndarray:
        """26-connected component id per voxel."""
        return _components(self.table, self.coords)

    def neighbourhood_sum(self, values: np.ndarray, radius: int = 1) -> np.ndarray:
        """Sum of a per-voxel quantity ``(V,)`` or ``(V, m)`` over each voxel's neighbourhood."""
        v = np.asarray(values, dtype=np.float64)
        out = _neighbourhood_sum(self.table, self.coords, v.reshape(v.shape[0], int(np.prod(v.shape[1:]))), radius)
        return out.reshape(v.shape)
