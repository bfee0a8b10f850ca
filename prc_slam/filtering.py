"""Label-driven point filtering before registration (PRC paper, Sec. V-B: "SLAM can be run on a
filtered and reduced stream of data"; "smart sampling as a function of the scan range").

Noise is dropped; ground is thinned to one point per cell of a horizontal grid (sensor frame)
rather than removed, so it still holds height and tilt; the other classes are sampled to one point
per cell of a 3-D grid whose size is chosen per class (``sample``). A cubic cell keeps every
point where the scan is sparser than the cell (far away) and one point per cell where it is denser
(near the sensor), so the sampling is a function of the scan range: it removes exactly the
near-range redundancy that KISS-ICP's own 0.5-voxel downsampling would discard after paying for
deskewing, cropping and hashing every point. Points PRC found one-sided (thin poles, trunks) are
never sampled away.

KISS-ICP registers a coarser subset (``source_cell``). Optionally (``source_dense=["ground"]``, off by
default: on held-out drives it bought accuracy with time at the rate more registered points do,
docs/RESULTS.md) it does not thin a class of ``source_dense`` where the scan samples it at least
as finely as ``dense_spacing`` (1/3 m): there every kept
point is registered, and KISS-ICP's own source voxel chooses among them as it does for all points
(the paper's "smart sampling as a function of the scan range", Sec. V-B, read off the scan's own
density rather than a range). The ground is the only class that fixes height, roll and pitch; where its
map is dense, a ground point's nearest map point lies straight below or above it, so each one holds
the vertical tightly, and thinning it there costs vertical accuracy that nothing else restores.
Where the rings are far apart, a ground point's correspondence is loose along the surface, and the
coarse grid loses little. The test is the coverage of the kept point's map cell (every sub-cell
of side ``dense_spacing`` holds a point: the rings are that close, not only the points along a ring),
so it follows the sensor (beam count, mounting height) without a range constant.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from prc_slam import labels as L


class FilterConfig(BaseModel):
    """What reaches the registration (measured on simulated 300-frame hdl64 drives with
    deskewing, times and ATE relative to all points; docs/RESULTS.md): noise dropped; for the map,
    ground on a 1 m horizontal grid (KISS-ICP's map voxel at its default 100 m range), vegetation
    on 1 m and everything else on 0.5 m cubes, each cell by a pseudo-random point of it
    (``representative``); KISS-ICP registers ground on a 5 m grid, buildings on 4 m and vegetation
    on 3 m cubes and all the rest. Urban drives, seeds 1 / 2: ATE x1.04 / x1.04 raw at time
    x0.52 / x0.53 (the next frame's PRC beside the registration). Height, roll and pitch, which the
    sparse registered ground holds loosely, are refined point to plane after the registration from
    the kept ground (its 1 m grid) by the odometry (``odometry.ground``,
    :mod:`prc_slam.odometry.ground`). Ground on 3 m, registered on
    10 m (the policy before) was faster (x0.03 less here, x0.08 on KITTI) but lost accuracy (ATE
    x1.38 / x1.34): sparse ground holds the height and tilt too loosely. Registered ground on 3 m
    was more accurate still (x0.82 / x0.95) but lost a 16-beam walk read at one sweep in 30 (3 m
    steps) that 5 m and 10 m hold: many registered ground points pull a poor initial guess towards
    staying put.
    Densely sampled ground (``source_dense``, ``dense_spacing``: every 1/3 m sub-cell of its 1 m
    cell holds a point) registered in full, measured on tuning drives (hdl64, 150 frames, seeds
    200-202, against the coarse grids alone / all points): per-frame vertical error 8-10 mm
    (11-17 / 4-5), roll 78-97 mdeg (89-130 / 32-43), ATE 0.023 / 0.024 / 0.029 m (0.028 / 0.027 /
    0.034 and 0.023 / 0.028 / 0.037) with ~610 source points (~520 / ~1300). ``dense_spacing: 0.5``
    (~700 source points; vertical 6-7 mm, roll 65-77 mdeg) lost the 16-beam walk at 3 m steps.
    On held-out drives (seeds 100-109, 300 frames) ``source_dense=["ground"]`` moved prc/raw ATE
    from 1.27 to 1.17 (median) and time from 0.51 to 0.59: the trade of registering more points,
    so it is off by default (``FilterConfig(source_dense=["ground"])`` turns it on);
    ``FilterConfig(cell=3.0, source_cell={"ground": 10.0, "building": 4.0, "vegetation": 3.0})``
    the policy before that; ``FilterConfig(cell=1.0, sample={}, sample_other=0, source_cell={})``
    is the earliest (noise dropped, ground on 1 m, all else kept)."""

    model_config = ConfigDict(extra="forbid")

    drop: list[int] = Field(default_factory=lambda: [L.NOISE], description="codes removed entirely")
    thin: list[int] = Field(default_factory=lambda: [L.GROUND], description="codes thinned on a horizontal grid")
    cell: float = Field(1.0, gt=0, description="horizontal grid cell (m) of the thinned classes; one point per cell")
    sample: dict[str, float] = Field(
        default_factory=lambda: {"vegetation": 1.0},
        description="class name -> 3-D grid cell (m): one point per cell of that class (0: keep all)",
    )
    sample_other: float = Field(
        0.5, ge=0, description="3-D grid cell (m) of the classes neither thinned, dropped nor in `sample` (0: keep all)"
    )
    source_cell: dict[str, float] = Field(
        default_factory=lambda: {"ground": 5.0, "building": 4.0, "vegetation": 3.0},
        description="class name -> cell (m) of the points KISS-ICP registers (its source; horizontal grid for the "
        "thinned classes, 3-D otherwise); the map still gets every kept point. Unlisted: every kept point",
    )
    source_dense: list[str] = Field(
        default_factory=list,
        description="classes registered in full (KISS-ICP's own source voxel) where the scan samples them at least "
        "as finely as `dense_spacing` in both directions (every sub-cell of that side of their map cell holds a point; "
        "for a cube, as many as a surface crossing it), and on their `source_cell` grid elsewhere. Empty: the "
        "`source_cell` grids everywhere",
    )
    dense_spacing: float = Field(
        0.33,
        gt=0,
        description="point spacing (m) at or below which a class of `source_dense` counts as densely sampled (its "
        "map cell is cut into round(cell / dense_spacing) parts along each axis, at most 8 (4 for a cube): 3 x 3 for "
        "the 1 m ground cell). "
        "0.5 (KISS-ICP's map voxel) also registers the 16-beam rings within ~5 m and lost a walk read at one sweep "
        "in 30 (3 m steps)",
    )
    source_exclude: list[str] = Field(
        default_factory=list,
        description="classes kept for the map but never registered (e.g. vegetation in strong wind)",
    )
    keep_one_sided: bool = Field(
        True, description="keep noise points that meet one of the two support conditions of eq. (4) (thin poles)"
    )
    representative: Literal["random", "first"] = Field(
        "random",
        description="the point kept per cell, and the order of the points given to registration: random (a "
        "pseudo-random point, hash of its index; handed over in that order so that KISS-ICP's voxels keep one too) "
        "or first (the sensor's order)",
    )


@dataclass
class FilterResult:
    """Mask of the kept points and the counts per class (in and kept)."""

    keep: np.ndarray
    counts_in: dict[str, int]
    counts_kept: dict[str, int]
    source: np.ndarray | None = None  # mask of the points to register (a subset of ``keep``); None: all kept
    order: np.ndarray | None = None  # indices of the kept points in registration order (None: input order)

    @property
    def kept_in_order(self) -> np.ndarray:
        """Indices of the kept points, in the order to give them to registration."""
        return np.flatnonzero(self.keep) if self.order is None else self.order

    @property
    def n_in(self) -> int:
        return len(self.keep)

    @property
    def n_kept(self) -> int:
        return int(self.keep.sum())


@njit(cache=True, nogil=True, inline="always")
def _priority(i):
    """Pseudo-random rank of point ``i`` (splitmix64 of its index): with ``representative="random"``
    the point of lowest rank stands for its cell."""
    z = np.uint64(i) + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, nogil=True)
def _filter_kernel(points, ids, labels, drop, planar, sample, spare, random, size, sub):
    """One pass: drop by class (except ``spare`` points); keep one point of every occupied cell,
    per class, of the horizontal grid (cell ``planar[c]``) of the thinned classes and of the 3-D
    grid (cell ``sample[c]``) of the sampled classes: the first one met, or with ``random`` the one
    of lowest :func:`_priority` of its id (open-addressing hash of (class, cell) with ``size``
    slots, a power of two, O(n)); count per class, and per kept point the occupied sub-cells of
    its cell (``occupancy``: the cell cut into ``sub[c]`` parts along each of its axes, at most 64
    sub-cells; 0 for points not gridded or classes with ``sub[c] == 0``). Returns ``None`` for
    ``keep`` when more than half the slots fill (call again with a larger ``size``)."""
    n = points.shape[0]
    n_cells = 0
    last_key, last_h, last_rank = np.int64(-1), 0, np.uint64(0)  # the cell of the previous point
    # one int64 key per (class, cell): 14 bits of class-and-plane flag, 3 x 16 bits of cell
    # coordinates (wrapped; two cells 65536 cells apart can share a key, never within a frame),
    # and beside it (same cache line) the index of the cell's point of lowest priority so far
    table = np.empty(2 * size, np.int64)
    table[0::2] = -1
    filled = np.zeros(size, np.uint64)  # occupied sub-cells per slot, one bit each
    keep = np.zeros(n, np.bool_)
    occupancy = np.zeros(n, np.int32)
    n_in = np.zeros(256, np.int64)
    n_kept = np.zeros(256, np.int64)
    inv_planar = np.zeros(256)
    inv_sample = np.zeros(256)
    for c in range(256):
        if planar[c] > 0:
            inv_planar[c] = 1.0 / planar[c]
        elif sample[c] > 0:
            inv_sample[c] = 1.0 / sample[c]
    for i in range(n):
        c = labels[i]
        n_in[c] += 1
        if spare[i]:
            keep[i] = True
            continue
        if drop[c]:
            continue
        inv = inv_planar[c] if inv_planar[c] > 0 else inv_sample[c]
        if inv > 0:
            cx = np.int64(np.floor(points[i, 0] * inv)) & 0xFFFF
            cy = np.int64(np.floor(points[i, 1] * inv)) & 0xFFFF
            cz = np.int64(0) if inv_planar[c] > 0 else np.int64(np.floor(points[i, 2] * inv)) & 0xFFFF
            key = (np.int64(c) << 48) | (cx << 32) | (cy << 16) | cz
            if key != last_key:  # successive returns often share a cell: then no look-up
                h = ((cx * 73856093) ^ (cy * 19349663) ^ (cz * 83492791) ^ (np.int64(c) * 2654435761)) & (size - 1)
                while table[2 * h] >= 0 and table[2 * h] != key:
                    h = (h + 1) & (size - 1)
                last_key, last_h = key, h
                if table[2 * h] != key:  # a new cell: this point stands for it, for now
                    n_cells += 1
                    if 2 * n_cells > size:
                        return None, n_in, n_kept, occupancy
                    table[2 * h] = key
                    table[2 * h + 1] = i
                    filled[h] = _sub_bit(points[i], inv, sub[c], inv_planar[c] > 0)
                    keep[i] = True
                    last_rank = _priority(ids[i])
                    continue
                if random:
                    last_rank = _priority(ids[table[2 * h + 1]])
            filled[last_h] |= _sub_bit(points[i], inv, sub[c], inv_planar[c] > 0)
            if random:
                rank = _priority(ids[i])
                if rank < last_rank:
                    keep[table[2 * last_h + 1]] = False
                    table[2 * last_h + 1] = i
                    keep[i] = True
                    last_rank = rank
            continue
        keep[i] = True
    for h in range(size):  # each cell's occupied sub-cells, on the point that stands for it
        if table[2 * h] >= 0:
            occupancy[table[2 * h + 1]] = _popcount(filled[h])
    for i in range(n):
        if keep[i]:
            n_kept[labels[i]] += 1
    return keep, n_in, n_kept, occupancy


@njit(cache=True, nogil=True, inline="always")
def _sub_bit(p, inv, k, planar):
    """The bit of the sub-cell of point ``p`` in its cell (``k`` parts along each axis of the
    cell, ``inv`` its inverse size; x-y only for a horizontal cell); 0 with ``k == 0``."""
    if k == 0:
        return np.uint64(0)
    sx = np.int64(np.floor(p[0] * inv * k)) - np.int64(np.floor(p[0] * inv)) * k
    sy = np.int64(np.floor(p[1] * inv * k)) - np.int64(np.floor(p[1] * inv)) * k
    b = sx * k + sy
    if not planar:
        b = b * k + np.int64(np.floor(p[2] * inv * k)) - np.int64(np.floor(p[2] * inv)) * k
    return np.uint64(1) << np.uint64(min(max(b, 0), 63))


@njit(cache=True, nogil=True, inline="always")
def _popcount(m):
    n = 0
    while m:
        m &= m - np.uint64(1)
        n += 1
    return n


def _filter(points, ids, labels, drop, planar, sample, spare, random, sub=None):
    """:func:`_filter_kernel` with a table for a quarter of the points as cells (a table for all
    of them, 4 MB for a 64-beam sweep, missed the cache on every look-up), four times larger while
    it fills up. ``sub``: per class, the parts along each axis of a cell whose occupancy is
    counted (none by default)."""
    sub = np.zeros(256, np.int64) if sub is None else sub
    size = 1 << max(10, int(np.ceil(np.log2(len(points) // 2 + 2))))
    while True:
        keep, n_in, n_kept, occupancy = _filter_kernel(
            points, ids, labels, drop, planar, sample, spare, random, size, sub
        )
        if keep is not None:
            return keep, n_in, n_kept, occupancy
        size *= 4


def registration_order(kept: np.ndarray) -> np.ndarray:
    """The kept points' indices in a pseudo-random order: by the top 16 bits of their
    :func:`_priority` hash (numpy's stable sort of 16-bit keys is a radix sort, O(k); ties keep
    input order). KISS-ICP keeps the first point of each voxel it meets, so the order decides which
    point stands for a voxel; in the sensor's order it is always the one the scan reached first, a
    representative biased by the scan pattern."""
    kept = np.asarray(kept, dtype=np.int64)
    return kept[np.argsort(_hash16(kept), kind="stable")]


@njit(cache=True, nogil=True)
def _hash16(ids):
    out = np.empty(len(ids), np.uint16)
    for k in range(len(ids)):
        out[k] = np.uint16(_priority(ids[k]) >> np.uint64(48))
    return out


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
    planar = np.where(thin, float(config.cell), 0.0)
    sample = np.zeros(256)
    sample[~drop & ~thin] = config.sample_other
    for name, size in config.sample.items():
        sample[_code(name, "sample", size)] = size
    spare = np.zeros(len(points), dtype=bool)
    if config.keep_one_sided and one_sided is not None:
        if np.shape(one_sided) != (len(points),):
            raise ValueError(f"one_sided has shape {np.shape(one_sided)} for {len(points)} points")
        spare = np.asarray(one_sided, dtype=bool) & drop[labels]  # spared from dropping only
    random = config.representative == "random"
    sub = _dense_parts(config, planar, sample) if config.source_cell or config.source_exclude else None
    keep, n_in, n_kept, occupancy = _filter(
        points, np.arange(len(points)), labels, drop, planar, sample, spare, random, sub
    )
    source = None
    if config.source_cell or config.source_exclude:
        s_drop = np.zeros(256, dtype=bool)
        for name in config.source_exclude:
            s_drop[_code(name, "source_exclude", 0.0)] = True
        s_planar, s_sample = np.zeros(256), np.zeros(256)
        for name, size in config.source_cell.items():
            c = _code(name, "source_cell", size)
            (s_planar if thin[c] else s_sample)[c] = size
        idx = np.flatnonzero(keep)
        # registered in full: the spared points, and the points of a dense class standing for a
        # cell whose every sub-cell holds a point
        dense = (sub[labels[idx]] > 0) & (occupancy[idx] >= sub[labels[idx]] ** 2)
        full = spare[idx] | (dense & ~s_drop[labels[idx]])
        chosen, _, _, _ = _filter(points[idx], idx, labels[idx], s_drop, s_planar, s_sample, full, random)
        source = np.zeros(len(points), dtype=bool)
        source[idx[chosen]] = True
    present = np.flatnonzero(n_in)
    counts_in = {L.CODE_TO_NAME.get(int(c), f"code_{c}"): int(n_in[c]) for c in present}
    counts_kept = {L.CODE_TO_NAME.get(int(c), f"code_{c}"): int(n_kept[c]) for c in present}
    order = registration_order(np.flatnonzero(keep)) if random else None
    return FilterResult(keep, counts_in, counts_kept, source, order)


def _dense_parts(config: FilterConfig, planar: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Per class code, the parts ``k`` along each axis of its map cell into which the cell is cut
    to test its coverage (``round(cell / dense_spacing)``, at most 8, 4 for a cube), 0 for the classes not in
    ``config.source_dense``: a cell counts as densely sampled when ``k ** 2`` of its sub-cells
    hold a point (all of them for a horizontal cell; as many as a surface crossing a cube)."""
    sub = np.zeros(256, np.int64)
    for name in config.source_dense:
        c = _code(name, "source_dense", 0.0)
        cell = planar[c] if planar[c] > 0 else sample[c]
        if cell <= 0:
            continue  # kept in full in the map: no cell to test
        # one bit per sub-cell in a 64-bit mask: a larger cell is tested at cell / 8 (cube: / 4)
        sub[c] = min(max(1, round(cell / config.dense_spacing)), 8 if planar[c] > 0 else 4)
    return sub


def _code(name: str, field: str, size: float) -> int:
    if name not in L.NAME_TO_CODE:
        raise ValueError(f"unknown class {name!r} in the filter's {field}; known: {sorted(L.NAME_TO_CODE)}")
    if size < 0:
        raise ValueError(f"{field} cell of {name!r} is negative ({size})")
    return L.NAME_TO_CODE[name]


def parse_keep_labels(values: Sequence[str | int] | str | None) -> list[int] | None:
    """Label names or codes (``"ground,building"``, ``["2", "vehicle"]``) → codes; None stays None."""
    if values is None:
        return None
    if isinstance(values, str):
        values = [values]
    codes: list[int] = []
    for v in values:
        for item in str(v).split(","):
            item = item.strip()
            if not item:
                continue
            if item.isdigit():
                code = int(item)
                if code not in L.CODE_TO_NAME:
                    raise ValueError(f"--keep-labels: unknown label code {code}; known: {sorted(L.CODE_TO_NAME)}")
            elif item in L.NAME_TO_CODE:
                code = L.NAME_TO_CODE[item]
            else:
                raise ValueError(f"--keep-labels: unknown label {item!r}; choose from {', '.join(L.NAME_TO_CODE)}")
            codes.append(code)
    if not codes:
        raise ValueError("--keep-labels names no label")
    return sorted(set(codes))


def choose_points(
    points: np.ndarray,
    labels: np.ndarray,
    config: FilterConfig,
    *,
    one_sided: np.ndarray | None = None,
    keep_labels: Sequence[int] | None = None,
) -> np.ndarray:
    """Mask of the points written to the filtered stream (input order).

    The filter policy of ``config`` (or, with ``keep_labels``, the listed classes only); points
    labelled ``no_return`` or with non-finite coordinates are never kept.
    """
    points = np.asarray(points)
    labels = np.asarray(labels, dtype=np.uint8)
    finite = np.isfinite(points).all(axis=1)
    if keep_labels is not None:
        keep = np.isin(labels, np.asarray(list(keep_labels), dtype=np.uint8))
    else:
        policy = config.model_copy(update={"drop": sorted(set(config.drop) | {L.NO_RETURN})})
        safe = np.where(finite[:, None], points, 0.0)
        keep = filter_points(safe, labels, policy, one_sided).keep
    return keep & finite & (labels != L.NO_RETURN)
