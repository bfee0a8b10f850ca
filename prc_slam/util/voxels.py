"""Sparse voxel grids, shared by the map classification (paper 004, Sec. 3.1, 3.3, 3.4, 4.2,
4.4) and the class-aware registration's correspondence search.

A grid is an open-addressing hash from integer voxel coordinates to a dense voxel index, built
in one O(N) pass (no sort), with int32 coordinates and table while the coordinates fit (half
the bytes each probe reads; the int64 build beyond). Flat (x-y) grids over a compact box use a
dense array of their cells instead of the hash (:attr:`VoxelGrid.plane`, :func:`find_cell`).
Everything is numba; callers get arrays. Large outputs are allocated by numpy and filled by the
kernels: numpy asks the kernel for huge pages on large arrays, numba's own allocations get 4 kB
pages, whose first touch costs about four times as much here.

On large grids the 3x3x3 neighbourhoods (sums, lists, components) are found by a merge walk over
the voxels sorted by a linear key (:func:`neighbour_lists`) instead of 27 hash probes per voxel:
the probes are random accesses into tables of tens of MB (a cache miss each), the walk reads
sorted arrays in order. Both give the same neighbours in the same order (dx, then dy, then dz
ascending), so sums are bit-identical.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from itertools import pairwise

import numpy as np
from numba import njit, prange

from prc_slam.util import unionfind as uf
from prc_slam.util.threads import side_by_side


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
def _build(points, inv_size, flat=False, offset=0.0):
    """Voxel index per point; the table doubles whenever it is half full. ``flat``: x-y cells
    (every z index 0, the z column is not read). A point in the voxel of the point before it
    skips the probe (scan-ordered clouds: ~20 % faster). ``offset`` is added to every
    coordinate first (the grid of ``points + offset`` without the copy)."""
    n = points.shape[0]
    size = 1024
    table = np.full(size, -1, np.int64)
    coords = np.empty((max(n, 1), 3), np.int64)
    voxel = np.empty(n, np.int64)
    nv = 0
    for i in range(n):
        x = np.int64(np.floor((points[i, 0] + offset) * inv_size))
        y = np.int64(np.floor((points[i, 1] + offset) * inv_size))
        z = np.int64(0) if flat else np.int64(np.floor((points[i, 2] + offset) * inv_size))
        if i > 0:
            u = voxel[i - 1]
            if coords[u, 0] == x and coords[u, 1] == y and coords[u, 2] == z:
                voxel[i] = u
                continue
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


#: voxel coordinates the compact (int32) build takes: beyond, the int64 build
_I32_LO, _I32_HI = -(2**31), 2**31 - 1


@njit(cache=True, nogil=True)
def _rehash32(coords, nv, size):
    """:func:`_rehash` into an int32 table (same slots, same order)."""
    mask = size - 1
    table = np.full(size, -1, np.int32)
    for v in range(nv):
        h = _slot(np.int64(coords[v, 0]), np.int64(coords[v, 1]), np.int64(coords[v, 2]), mask)
        while table[h] >= 0:
            h = (h + 1) & mask
        table[h] = v
    return table


@njit(cache=True, nogil=True)
def _build32(points, inv_size, flat, offset, voxel, coords):
    """:func:`_build` with int32 voxel coordinates and table (half the memory a probe reads:
    1.3-1.7x faster on grids of millions of voxels); the same voxels, order and table slots.
    Fills ``voxel`` (N,) and the first rows of ``coords`` (N, 3) int32, allocated by the caller
    (numpy: huge pages); returns the number of voxels, the table and ``ok``, False (the rest
    unusable) when a voxel coordinate does not fit int32."""
    n = points.shape[0]
    size = 1024
    table = np.full(size, -1, np.int32)
    nv = 0
    u = -1
    for i in range(n):
        x = np.int64(np.floor((points[i, 0] + offset) * inv_size))
        y = np.int64(np.floor((points[i, 1] + offset) * inv_size))
        z = np.int64(0) if flat else np.int64(np.floor((points[i, 2] + offset) * inv_size))
        if u >= 0 and coords[u, 0] == x and coords[u, 1] == y and coords[u, 2] == z:
            voxel[i] = u
            continue
        if not (_I32_LO <= x <= _I32_HI and _I32_LO <= y <= _I32_HI and _I32_LO <= z <= _I32_HI):
            return 0, table, False
        mask = size - 1
        h = _slot(x, y, z, mask)
        while True:
            v = np.int64(table[h])
            if v < 0:
                table[h] = nv
                coords[nv, 0], coords[nv, 1], coords[nv, 2] = x, y, z
                v = nv
                nv += 1
                if 2 * nv > size:
                    size *= 2
                    table = _rehash32(coords, nv, size)
                break
            if coords[v, 0] == x and coords[v, 1] == y and coords[v, 2] == z:
                break
            h = (h + 1) & mask
        voxel[i] = v
        u = v
    return nv, table, True


@njit(cache=True, nogil=True)
def _renumber(voxel, rows, new_of, out, old_of):
    """``out``: the voxels of ``voxel[rows]`` renumbered 0.. in order of first appearance;
    ``old_of``: the old index of each new one; ``new_of`` (all -1) is scratch. Their number."""
    nv = 0
    for k in range(rows.shape[0]):
        v = voxel[rows[k]]
        w = new_of[v]
        if w < 0:
            w = nv
            new_of[v] = w
            old_of[w] = v
            nv += 1
        out[k] = w
    return nv


@njit(cache=True, nogil=True)
def _counts(points, inv_size, offset, coords, counts):
    """Points per voxel of the grid :func:`_build32` makes of ``points + offset`` (same voxels,
    same order), without the per-point voxel index: the first rows of ``coords`` (N, 3) int32
    and ``counts`` (N,) filled; returns their number and ``ok`` as there."""
    n = points.shape[0]
    size = 1024
    table = np.full(size, -1, np.int32)
    nv = 0
    u = -1
    for i in range(n):
        x = np.int64(np.floor((points[i, 0] + offset) * inv_size))
        y = np.int64(np.floor((points[i, 1] + offset) * inv_size))
        z = np.int64(np.floor((points[i, 2] + offset) * inv_size))
        if u >= 0 and coords[u, 0] == x and coords[u, 1] == y and coords[u, 2] == z:
            counts[u] += 1
            continue
        if not (_I32_LO <= x <= _I32_HI and _I32_LO <= y <= _I32_HI and _I32_LO <= z <= _I32_HI):
            return 0, False
        mask = size - 1
        h = _slot(x, y, z, mask)
        while True:
            v = np.int64(table[h])
            if v < 0:
                table[h] = nv
                coords[nv, 0], coords[nv, 1], coords[nv, 2] = x, y, z
                counts[nv] = 0
                v = nv
                nv += 1
                if 2 * nv > size:
                    size *= 2
                    table = _rehash32(coords, nv, size)
                break
            if coords[v, 0] == x and coords[v, 1] == y and coords[v, 2] == z:
                break
            h = (h + 1) & mask
        counts[v] += 1
        u = v
    return nv, True


def voxel_counts(points: np.ndarray, size: float, offset: float = 0.0) -> np.ndarray:
    """``VoxelGrid.build(points, size, offset=offset).counts`` without the rest of the grid."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 2**31:
        counts = np.empty(max(len(pts), 1), np.int64)
        nv, ok = _counts(pts, 1.0 / size, float(offset), np.empty((max(len(pts), 1), 3), np.int32), counts)
        if ok:
            return counts[:nv].copy()
    return VoxelGrid.build(pts, size, offset=offset).counts


@njit(cache=True, nogil=True)
def _build_plane(points, inv_size, ix0, iy0, nx, ny, dense, voxel, coords):
    """Flat grid (x-y cells, z index 0) through a dense ``nx * ny`` array of cell indices
    (``dense``, all -1) over the cells ``ix0.., iy0..``: the cells of :func:`_build` (``flat``),
    numbered in the same order of first appearance, without hashing; fills ``voxel`` and the
    first rows of ``coords``. Returns their number and ``ok``, False when a point falls outside."""
    n = points.shape[0]
    nv = 0
    for i in range(n):
        x = np.int64(np.floor(points[i, 0] * inv_size))
        y = np.int64(np.floor(points[i, 1] * inv_size))
        a, b = x - ix0, y - iy0
        if a < 0 or a >= nx or b < 0 or b >= ny:
            return 0, False
        k = a * ny + b
        v = dense[k]
        if v < 0:
            v = nv
            dense[k] = v
            coords[v, 0], coords[v, 1], coords[v, 2] = x, y, 0
            nv += 1
        voxel[i] = v
    return nv, True


@njit(cache=True, nogil=True)
def _plane_bounds(points, inv_size):
    """Least and largest x and y cell index of the points (``floor(p * inv_size)`` is monotone
    in ``p``); ``ok`` False when a coordinate is not finite."""
    lo0, lo1, hi0, hi1 = np.inf, np.inf, -np.inf, -np.inf
    for i in range(points.shape[0]):
        x, y = points[i, 0], points[i, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            return 0, 0, 0, 0, False
        lo0, hi0 = min(lo0, x), max(hi0, x)
        lo1, hi1 = min(lo1, y), max(hi1, y)
    if points.shape[0] == 0:
        return 0, 0, 0, 0, False
    return (
        np.int64(np.floor(lo0 * inv_size)), np.int64(np.floor(lo1 * inv_size)),
        np.int64(np.floor(hi0 * inv_size)), np.int64(np.floor(hi1 * inv_size)), True,
    )  # fmt: skip


def _rows(n: int, dtype=np.int64) -> np.ndarray:
    """Room for up to ``n`` voxel coordinates (N, 3), allocated by numpy (huge pages on large
    arrays; numba's allocations get 4 kB pages, whose first touch costs ~4x more); the pages
    a kernel leaves untouched are never mapped."""
    return np.empty((max(n, 1), 3), dtype)


def _table_size(nv: int) -> int:
    """The size :func:`_build` ends with for ``nv`` voxels (1024, doubled while half full)."""
    size = 1024
    while 2 * nv > size:
        size *= 2
    return size


#: a flat grid uses a dense array of cells when its x-y box has at most this many cells per point
PLANE_CELLS_PER_POINT = 2.0

#: the dense plane of a grid without one: no cells
NO_PLANE = (np.zeros(0, np.int32), 0, 0, 0, 0)


@njit(cache=True, nogil=True, inline="always")
def find_cell(plane, table, coords, x, y):
    """Index of cell ``(x, y)`` of a flat grid or -1: from its dense ``plane`` (``(cells, ix0,
    iy0, nx, ny)``) when it has one, else :func:`find` at z = 0."""
    dense, ix0, iy0, nx, ny = plane
    if dense.shape[0] == 0:
        return find(table, coords, x, y, 0)
    a, b = x - ix0, y - iy0
    if a < 0 or a >= nx or b < 0 or b >= ny:
        return -1
    return np.int64(dense[a * ny + b])


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
                        uf.union(parent, v, u)
    return uf.component_ids(parent)


@njit(cache=True, nogil=True)
def group_members(keys, n_groups):
    """Indices ``0..N-1`` grouped by ``keys`` (ints in ``[0, n_groups)``) by counting sort, O(N +
    groups), input order kept within a group: ``members[start[g]:start[g + 1]]`` are group ``g``'s."""
    n = keys.shape[0]
    start = np.zeros(n_groups + 1, np.int64)
    for i in range(n):
        start[keys[i] + 1] += 1
    for g in range(n_groups):
        start[g + 1] += start[g]
    fill = start[:-1].copy()
    members = np.empty(n, np.int64)
    for i in range(n):
        members[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return start, members


def radix_argsort(keys: np.ndarray) -> np.ndarray:
    """Argsort of non-negative int64 keys (LSD radix sort, 16-bit digits; stable). O(N) per
    16 bits of the largest key."""
    return _radix_sort(np.asarray(keys, dtype=np.int64))[0]


def _radix_sort(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stable argsort of non-negative int64 ``keys`` and the sorted keys: LSD radix sort
    with 16-bit digits, the keys carried along with their indices (each pass reads both in
    order), scratch allocated by numpy (huge pages). The permutation of a stable sort is
    unique: the same as ``np.argsort(keys, kind="mergesort")``."""
    n = len(keys)
    if n < 4096:
        order = np.argsort(keys, kind="mergesort")
        return order, keys[order]
    k1, k2 = keys.astype(np.int64).view(np.uint64), np.empty(n, np.uint64)  # the same order, >= 0
    i1, i2 = np.arange(n, dtype=np.int64), np.empty(n, np.int64)
    flip = radix_passes(k1, i1, k2, i2)
    return (i2, k2.view(np.int64)) if flip else (i1, k1.view(np.int64))


@njit(cache=True, nogil=True)
def radix_passes(k1, i1, k2, i2):
    """Stable LSD radix sort of uint64 keys ``k1`` with their indices ``i1``, 16 bits at a time
    up to the largest key, from (``k1``, ``i1``) into (``k2``, ``i2``) and back; a digit that is
    the same for every key is skipped (the pass would change nothing). True when the result
    ended in (``k2``, ``i2``)."""
    n = k1.shape[0]
    kmax = k1.max() if n else np.uint64(0)
    cnt = np.empty(65536, np.int64)
    flip = False
    for shift in range(0, 64, 16):
        sh = np.uint64(shift)
        if (kmax >> sh) == 0:
            break
        cnt[:] = 0
        for i in range(n):
            cnt[np.int64((k1[i] >> sh) & np.uint64(0xFFFF))] += 1
        if cnt.max() == n:
            continue  # every key has this digit
        tot = 0
        for d in range(65536):
            c = cnt[d]
            cnt[d] = tot
            tot += c
        for i in range(n):
            d = np.int64((k1[i] >> sh) & np.uint64(0xFFFF))
            j = cnt[d]
            k2[j] = k1[i]
            i2[j] = i1[i]
            cnt[d] = j + 1
        k1, k2 = k2, k1
        i1, i2 = i2, i1
        flip = not flip
    return flip


@njit(cache=True, nogil=True)
def _linear_keys(coords, keys):
    """Linear key ``((x+1) ny + y+1) nz + z+1`` (offsets from the minimum, one spare layer each
    side) of every voxel into ``keys``; returns ``ny``, ``nz``, ``ny = -1`` when the keys would
    overflow int64."""
    nv = coords.shape[0]
    if nv == 0:
        return 1, 1
    lo0, lo1, lo2 = coords[:, 0].min(), coords[:, 1].min(), coords[:, 2].min()
    nx = coords[:, 0].max() - lo0 + 3
    ny = coords[:, 1].max() - lo1 + 3
    nz = coords[:, 2].max() - lo2 + 3
    if float(nx) * float(ny) * float(nz) >= 2.0**62:
        return -1, -1
    for v in range(nv):
        keys[v] = ((coords[v, 0] - lo0 + 1) * ny + (coords[v, 1] - lo1 + 1)) * nz + (coords[v, 2] - lo2 + 1)
    return ny, nz


def _sorted_keys(coords: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Voxels sorted by linear key: the order, the sorted keys and the key offsets of the nine
    (dx, dy) columns around a voxel (dx, then dy ascending); None when the keys would overflow."""
    keys = np.empty(len(coords), np.int64)
    ny, nz = _linear_keys(coords, keys)
    if ny < 0:
        return None
    order, sk = _radix_sort(keys)
    offs = np.array([dx * ny * nz + dy * nz for dx in (-1, 0, 1) for dy in (-1, 0, 1)], np.int64)
    return order, sk, offs


def _merge_neighbours(coords: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3x3x3 neighbour lists (CSR, the voxel itself included) in the order of
    :func:`_neighbours` without the empty slots: a merge walk over the voxels sorted by linear
    key, one monotone pointer per (dx, dy) column, writing the lists in sorted order; then each
    list moved to its voxel's place in input order. Large grids walk and move their two halves
    of the sorted order side by side (:func:`prc_slam.util.threads.side_by_side`; the same lists).
    ``start`` is empty when the keys overflow."""
    nv = len(coords)
    sorted_keys = _sorted_keys(coords)
    if sorted_keys is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int32)
    order = sorted_keys[0]
    walk = np.empty(27 * max(nv, 1), np.int32)  # at most 27 a voxel; untouched pages stay unmapped
    length = np.empty(nv, np.int64)
    cuts = (0, nv // 2, nv) if nv >= SPLIT_MIN_VOXELS else (0, nv)
    halves = list(pairwise(cuts))
    side_by_side(*(partial(_merge_walk_range, *sorted_keys, walk, length, lo, hi) for lo, hi in halves))
    start = np.zeros(nv + 1, np.int64)
    _list_starts(order, length, start)
    nbr = np.empty(int(start[-1]), np.int32)
    side_by_side(*(partial(_place_range, order, walk, length, start, nbr, lo, hi) for lo, hi in halves))
    return start, nbr


#: grids with at least this many voxels walk their neighbour lists in two halves side by side
SPLIT_MIN_VOXELS = 200_000


@njit(cache=True, nogil=True)
def _merge_walk_range(order, sk, offs, walk, length, lo, hi):
    """The lists of the voxels at sorted positions ``lo..hi-1``, one after another in ``walk``
    from ``walk[27 * lo]``; their lengths. Each column pointer starts where the walk from 0
    would have left it (the first key not below the column's lowest)."""
    nv = order.shape[0]
    ptr = np.zeros(9, np.int64)
    if lo < nv:
        for o in range(9):
            ptr[o] = np.searchsorted(sk, sk[lo] + offs[o] - 1)
    a = 27 * lo
    for i in range(lo, hi):
        a0 = a
        for o in range(9):
            t = sk[i] + offs[o]
            p = ptr[o]
            while p < nv and sk[p] < t - 1:
                p += 1
            ptr[o] = p
            while p < nv and sk[p] <= t + 1:
                walk[a] = order[p]
                a += 1
                p += 1
        length[i] = a - a0


@njit(cache=True, nogil=True)
def _list_starts(order, length, start):
    """CSR starts in input order (``start`` zeros) from the lengths in sorted order."""
    nv = order.shape[0]
    for i in range(nv):
        start[order[i] + 1] = length[i]
    for v in range(nv):
        start[v + 1] += start[v]


@njit(cache=True, nogil=True)
def _place_range(order, walk, length, start, nbr, lo, hi):
    """The lists of sorted positions ``lo..hi-1`` (from ``walk[27 * lo]``) moved to their
    voxels' places in ``nbr``."""
    a = 27 * lo
    for i in range(lo, hi):
        b = start[order[i]]
        for j in range(length[i]):
            nbr[b + j] = walk[a + j]
        a += length[i]


def _merge_sum(coords: np.ndarray, values: np.ndarray, out: np.ndarray) -> tuple[np.ndarray, bool]:
    """:func:`_neighbourhood_sum` (radius 1) by one merge walk, without lists (same order of
    addition, so bit-identical), added into ``out`` (zeros). ``ok`` is False when the keys
    would overflow."""
    sorted_keys = _sorted_keys(coords)
    if sorted_keys is None:
        return out, False
    _merge_sum_walk(*sorted_keys, values, out)
    return out, True


@njit(cache=True, nogil=True)
def _merge_sum_walk(order, sk, offs, values, out):
    nv, m = values.shape
    ptr = np.zeros(9, np.int64)
    for i in range(nv):
        v = order[i]
        for o in range(9):
            t = sk[i] + offs[o]
            p = ptr[o]
            while p < nv and sk[p] < t - 1:
                p += 1
            ptr[o] = p
            while p < nv and sk[p] <= t + 1:
                u = order[p]
                for c in range(m):
                    out[v, c] += values[u, c]
                p += 1


@njit(cache=True, nogil=True)
def _hash_neighbours(table, coords):
    """As :func:`_merge_neighbours`, by 27 hash probes per voxel (small grids, huge extents)."""
    nv = coords.shape[0]
    start = np.zeros(nv + 1, np.int64)
    nbr = np.empty(27 * nv, np.int32)
    m = 0
    for v in range(nv):
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    u = find(table, coords, coords[v, 0] + dx, coords[v, 1] + dy, coords[v, 2] + dz)
                    if u >= 0:
                        nbr[m] = u
                        m += 1
        start[v + 1] = m
    return start, nbr[:m].copy()


@njit(cache=True, nogil=True, parallel=True)
def _lists_sum(start, nbr, values, out):
    """Sums over the neighbour lists into ``out`` (zeros); voxels are independent (parallel
    loop, each sum added in list order: the result does not depend on the thread count)."""
    nv, m = values.shape
    for v in prange(nv):
        for j in range(start[v], start[v + 1]):
            u = nbr[j]
            for c in range(m):
                out[v, c] += values[u, c]
    return out


@njit(cache=True, nogil=True)
def _lists_components(start, nbr):
    """:func:`_components` on neighbour lists (same union order, same ids)."""
    nv = start.shape[0] - 1
    parent = np.arange(nv)
    for v in range(nv):
        for j in range(start[v], start[v + 1]):
            u = nbr[j]
            if u > v:
                uf.union(parent, v, u)
    return uf.component_ids(parent)


#: grids with more voxels than this use the merge walk for their 3x3x3 neighbourhoods
MERGE_MIN_VOXELS = 20_000


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
    table : int32 or int64 (power of two,)
        The hash of the voxels for :func:`find` (made on first use for grids with a ``plane``).
    """

    size: float
    voxel: np.ndarray
    coords: np.ndarray
    _table: np.ndarray | None
    counts: np.ndarray
    _lists: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False, compare=False)
    #: flat grids over a compact x-y box: ``(cells, ix0, iy0, nx, ny)``, the index of every cell
    #: of the box (-1 empty) at ``cells[(x - ix0) * ny + y - iy0]`` (:func:`find_cell`)
    plane: tuple = field(default=NO_PLANE, repr=False, compare=False)

    @classmethod
    def build(cls, points: np.ndarray, size: float, flat: bool = False, offset: float = 0.0) -> VoxelGrid:
        """Grid of ``points`` (N, 3) in cubes of side ``size``; ``flat``: of their x-y cells
        (z index 0 for all; the same grid as of the points with z set to 0, without the copy);
        ``offset``: the grid of ``points + offset`` (the same floating-point sums), without the copy.
        A flat grid whose x-y box has at most :data:`PLANE_CELLS_PER_POINT` cells per point is
        built through a dense array of its cells (``plane``; the same cells in the same order)
        and gets its hash table only when asked for it."""
        pts = np.asarray(points, dtype=np.float64)
        if flat and offset == 0.0:
            x0, y0, x1, y1, ok = _plane_bounds(pts, 1.0 / size)
            nx, ny = x1 - x0 + 1, y1 - y0 + 1
            if ok and float(nx) * float(ny) <= PLANE_CELLS_PER_POINT * len(pts) + 4096 and len(pts) < 2**31:
                cells, voxel, coords = np.full(nx * ny, -1, np.int32), np.empty(len(pts), np.int64), _rows(len(pts))
                nv, ok = _build_plane(pts, 1.0 / size, x0, y0, nx, ny, cells, voxel, coords)
                if ok:
                    plane = (cells, x0, y0, nx, ny)
                    coords = coords[:nv].copy()
                    return cls(size, voxel, coords, None, np.bincount(voxel, minlength=nv), plane=plane)
        ok = False
        if len(pts) < 2**31:
            voxel, coords = np.empty(len(pts), np.int64), _rows(len(pts), np.int32)
            nv, table, ok = _build32(pts, 1.0 / size, flat, float(offset), voxel, coords)
            coords = coords[:nv].astype(np.int64)
        if not ok:
            voxel, coords, table = _build(pts, 1.0 / size, flat, float(offset))
        return cls(size, voxel, coords, table, np.bincount(voxel, minlength=len(coords)))

    @property
    def probe_table(self) -> np.ndarray:
        """The hash table for :func:`find_cell`: the grid's own, or an empty stand-in (one free
        slot) when its ``plane`` answers and the table was never made."""
        return self._table if self._table is not None else np.full(1, -1, np.int64)

    @property
    def table(self) -> np.ndarray:
        """The open-addressing hash table of the voxels (:func:`find`); made on first use for
        grids built through a dense plane (the table :func:`_build` would have made)."""
        if self._table is None:
            self._table = _rehash32(self.coords, self.n_voxels, _table_size(self.n_voxels))
        return self._table

    @property
    def n_voxels(self) -> int:
        return len(self.coords)

    def subset(self, rows: np.ndarray) -> VoxelGrid:
        """The grid :meth:`build` makes of the points ``rows`` (indices, increasing or not) of
        this grid's points, at the same size: the same cubes, numbered in the order of first
        appearance among those rows, without binning the points again."""
        rows = np.asarray(rows, dtype=np.int64)
        voxel = np.empty(len(rows), np.int64)
        old = np.empty(max(len(rows), 1), np.int64)
        nv = _renumber(self.voxel, rows, np.full(self.n_voxels, -1, np.int64), voxel, old)
        coords = self.coords[old[:nv]]
        return VoxelGrid(self.size, voxel, coords, None, np.bincount(voxel, minlength=nv))

    def neighbours(self, radius: int = 1) -> np.ndarray:
        """Indices of the ``(2r+1)^3`` voxels around every voxel (itself included), -1 where empty."""
        return _neighbours(self.table, self.coords, radius)

    def neighbour_lists(self) -> tuple[np.ndarray, np.ndarray]:
        """The occupied voxels of every 3x3x3 neighbourhood (the voxel itself included) as CSR
        lists: ``nbr[start[v]:start[v + 1]]`` (int32), in the order of :meth:`neighbours` without
        its -1 entries. Computed once per grid (merge walk on large grids, hash probes on small
        ones or when the linear keys would overflow)."""
        if self._lists is None:
            start = np.zeros(0, np.int64)
            if self.n_voxels > MERGE_MIN_VOXELS:
                start, nbr = _merge_neighbours(self.coords)
            if len(start) == 0:
                start, nbr = _hash_neighbours(self.table, self.coords)
            self._lists = (start, nbr)
        return self._lists

    def components(self) -> np.ndarray:
        """26-connected component id per voxel."""
        if self.n_voxels > MERGE_MIN_VOXELS:
            return _lists_components(*self.neighbour_lists())
        return _components(self.table, self.coords)

    def neighbourhood_sum(self, values: np.ndarray, radius: int = 1) -> np.ndarray:
        """Sum of a per-voxel quantity ``(V,)`` or ``(V, m)`` over each voxel's neighbourhood."""
        v = np.asarray(values, dtype=np.float64)
        flat = v.reshape(v.shape[0], int(np.prod(v.shape[1:])))
        ok = False
        if radius == 1 and self._lists is not None:
            out, ok = _lists_sum(*self._lists, flat, np.zeros(flat.shape)), True
        elif radius == 1 and self.n_voxels > MERGE_MIN_VOXELS:
            out, ok = _merge_sum(self.coords, flat, np.zeros(flat.shape))
        if not ok:
            out = _neighbourhood_sum(self.table, self.coords, flat, radius)
        return out.reshape(v.shape)
