"""The curb algorithm of Stamos et al. (paper 001), Sec. 6.

(a) Within each scan line, a possible curb point (PC) is the first vertical return after the
last ground return for which TestUnder is false (Sec. 7.3: no return among the previous
``L = 30`` lies farther from the scanner than it), searched only up to ``t_high`` above the
ground height. Read online, "the last ground point" is the latest one seen, so the search
restarts after every run of ground (a sidewalk found as ground no longer hides the curb in
front of it; ``last_only`` keeps the offline reading, one PC after the line's final ground
return). (b) Vertical returns are grouped into connected regions across scan lines; a
region containing a PC is a curb if its height is at most ``t_curb = 0.2 m`` and it spans at
least three scan lines, or fewer with a small median vertical curvature.

TestUnder's slack is the paper's 0.01 m (Sec. 7.3, footnote 3). Ours, where the paper gives
no number: the curvature test as the median absolute change of the signed angle
(``max_curvature`` 30 deg, on regions of at least 3 points); region growing joins
4-neighbours of the range image (rows of one scan line, neighbouring lines) that lie at most
``max_gap`` = 0.5 m apart, so that a curb face does not merge with the car parked in front of
it (``inf``: the range image alone); and regions lower than ``min_height`` = 5 cm are no
curb (returns of the road at an occlusion edge, e.g. under a car, take steep signed angles).
Measured on 12 simulated profiler-urban blocks, paper readings -> ours: curb sections found
31 -> 46 of 46, curb recall 0.54 -> 0.81.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
from numba import njit

from prc_slam.online import kernels as K
from prc_slam.online.coarse import CoarseResult, elevation_rows, line_values
from prc_slam.prc import kernels as prc_kernels
from prc_slam.scan import Scan, SpinningSensor


@njit(cache=True, nogil=True)
def possible_curbs(xyz, codes, ground, valid, lines, z_line, t_high, look_back, under_eps, last_only):
    """Part (a): possible curb points (slot indices; ``-1`` pads), ``int64[L, n]``.

    Read online, "the last ground point" is the latest one seen: after every ground return the
    search restarts, so a line may hold a PC behind each run of ground (``last_only`` keeps only
    the PC after the line's final ground return, the paper read offline).
    """
    n_lines, width = lines.shape
    out = np.full((n_lines, max(1, width // 2)), -1, np.int64)
    pts_b = np.empty(width, np.int64)  # per-line buffers, made once (no allocation in the loop)
    rng_b = np.empty(width)
    for li in range(n_lines):
        m = K.line_returns_into(lines[li], valid, pts_b)
        pts = pts_b[:m]
        first = 0
        if last_only:
            for k in range(m):
                if ground[pts[k]]:
                    first = k
        found = 0
        searching = False
        rng = rng_b[:m]  # distance from the scanner of each return, computed when first needed
        n_rng = 0
        for k in range(first, m):
            s = pts[k]
            if ground[s]:
                searching = True
                continue
            if not searching:
                continue
            if xyz[s, 2] > z_line[li] + t_high:
                searching = False
                continue
            if codes[s] != 69:
                continue
            lo = max(0, k - look_back)
            n_rng = max(n_rng, lo)  # returns before the window are never looked at
            while n_rng <= k:
                q = pts[n_rng]
                rng[n_rng] = np.sqrt(xyz[q, 0] ** 2 + xyz[q, 1] ** 2 + xyz[q, 2] ** 2)
                n_rng += 1
            d = rng[k]
            far = 0.0
            for j in range(lo, k):
                far = max(far, rng[j])
            if far - d <= under_eps:  # TestUnder false: nothing earlier lies behind it
                out[li, found] = s
                found += 1
                searching = False
    return out


@dataclass
class CurbParams:
    t_high: float = 2.0
    look_back: int = 30
    under_eps: float = 0.01  # Sec. 7.3, footnote 3
    t_curb: float = 0.2
    min_height: float = 0.05  # ours (0 = paper): flatter regions are no curb (occlusion edges on the road)
    min_lines: int = 3
    max_curvature: float = 30.0
    max_gap: float = 0.5  # region growing joins neighbours at most this far apart (m); inf: range image only
    last_only: bool = False  # True: one PC per line, after its final ground return
    # m, spinning sensors: a region is no curb where its beams lie farther apart up its columns than this (median
    # range x gap to the next beam up): a vertical region seen by one ring there (a facade's foot) measures no
    # height, whether it goes on up between the beams or not (inf: the paper's test on every region)
    max_spacing: float = 0.4


@dataclass
class CurbResult:
    """Curb returns per slot and one polyline (sensor frame, ordered along the curb) per curb."""

    mask: np.ndarray
    polylines: list[np.ndarray] = field(default_factory=list)
    possible: np.ndarray | None = None


def detect_curbs(
    scan: Scan,
    coarse: CoarseResult,
    ground: np.ndarray,
    z_ground: float | np.ndarray | None,
    params: CurbParams | None = None,
) -> CurbResult:
    """Curbs of one scan (Sec. 6), given the coarse classes, the ground mask and the ground
    height (one for the scan, or one per scan line of :func:`scan_lines`)."""
    p = params or CurbParams()
    mask = np.zeros(scan.shape, dtype=bool)
    if z_ground is None:
        return CurbResult(mask)
    xyz = scan.slot_xyz()
    xyz64 = scan.slot_xyz64()
    lines = coarse.lines
    pc = possible_curbs(
        xyz64,
        coarse.codes.ravel(),
        ground.ravel(),
        scan.valid.ravel(),
        lines,
        line_values(z_ground, len(lines)),
        p.t_high,
        p.look_back,
        p.under_eps,
        p.last_only,
    ).ravel()
    pc = pc[pc >= 0]
    possible = np.zeros(scan.shape, dtype=bool)
    possible.ravel()[pc] = True
    vertical = coarse.codes == 69
    wrap = isinstance(scan.sensor, SpinningSensor)
    # region growing over range-image neighbours: a spinning sensor's rows in elevation order, so
    # that neighbouring rows are neighbouring beams whatever order the reader gave them in
    rows = elevation_rows(scan.sensor.altitude) if wrap else slice(None)
    regions_o, n = prc_kernels.connected_components_within(
        vertical[rows], xyz64.reshape(xyz.shape)[rows], p.max_gap, wrap
    )
    if isinstance(rows, slice):  # the same regions in the reader's row order, contiguous (every later
        regions = np.ascontiguousarray(regions_o[rows])  # pass reads them in memory order; ravel makes no copy)
    else:
        regions = np.empty_like(regions_o)
        regions[rows] = regions_o
    if n == 0 or len(pc) == 0:
        return CurbResult(mask, [], possible)
    zmin, zmax, size, n_lines = region_stats(regions, xyz[..., 2], n, wrap)
    has_pc = np.zeros(n + 1, dtype=bool)
    has_pc[regions.ravel()[pc]] = True
    ok = has_pc & (zmax - zmin <= p.t_curb) & (zmax - zmin >= p.min_height)
    if wrap and np.isfinite(p.max_spacing):
        ok &= region_spacing(scan, regions, n, np.flatnonzero(ok)) <= p.max_spacing
    short = np.flatnonzero(ok & (n_lines < p.min_lines))
    if len(short):  # few scan lines: accept only with >= 3 points and a small median curvature
        lab = regions.ravel()
        is_short = np.zeros(n + 1, bool)
        is_short[short] = True
        members = flagged_slots(lab, is_short)  # the slots of these regions only
        sv = coarse.sv.ravel()
        curv = np.abs(sv[members] - sv[_line_before(scan, members)])  # as np.diff along axis 0, sv[:1] prepended
        median = group_medians(lab[members], curv, short).astype(curv.dtype)  # float32, as np.median gives
        ok[short] = (size[short] >= 3) & (median <= p.max_curvature)
    ok[0] = False
    mask = K.relabel(regions, ok)  # ok[regions]
    return CurbResult(mask, _polylines(regions, ok, _line_index(scan), xyz), possible)


def beam_gap_up(altitude: np.ndarray) -> np.ndarray:
    """Each beam's elevation gap to the next beam up (rad; the highest beam: its gap down), in
    the given row order; one beam: 0."""
    alt = np.asarray(altitude, dtype=np.float64)
    if len(alt) < 2:
        return np.zeros(len(alt))
    order = np.argsort(alt, kind="stable")
    gaps = np.diff(alt[order])
    up = np.empty(len(alt))
    up[order[:-1]] = gaps
    up[order[-1]] = gaps[-1]
    return up


def region_spacing(scan: Scan, regions: np.ndarray, n: int, which: np.ndarray | None = None) -> np.ndarray:
    """Per region ``0..n``: the median over its slots of range x the gap to the next beam up (m),
    the vertical spacing of a spinning sensor's beams on a vertical surface there (index 0, regions
    without slots and those not in ``which``, if given: 0)."""
    out = np.zeros(n + 1)
    wanted = np.zeros(n + 1, bool)
    if which is None:
        wanted[:] = True
    else:
        wanted[which] = True
    wanted[0] = False
    ids, spacing = region_spacings(regions, wanted, scan.ranges, beam_gap_up(scan.sensor.altitude))
    if len(ids) == 0:
        return out
    groups = np.unique(ids)
    out[groups] = group_medians(ids, spacing, groups)
    return out


@njit(cache=True, nogil=True)
def region_spacings(regions, wanted, ranges, gap_up):
    """The slots of the ``wanted`` regions of ``regions`` (rows, cols), in image order: their region id
    and their range x the gap to the next beam up (``gap_up`` per row; as float32, the medians'
    type), in one pass over the image."""
    R, C = regions.shape
    ids = np.empty(R * C, np.int64)
    spacing = np.empty(R * C, np.float32)
    m = 0
    for r in range(R):
        for c in range(C):
            k = regions[r, c]
            if wanted[k]:
                ids[m] = k
                spacing[m] = np.float32(np.float64(ranges[r, c]) * gap_up[r])
                m += 1
    return ids[:m].copy(), spacing[:m].copy()


@njit(cache=True, nogil=True)
def flagged_slots(ids, flags):
    """``np.flatnonzero(flags[ids])`` (``ids`` flat, e.g. region ids per slot; ``flags`` per id) in one
    pass, without the mask over every slot."""
    out = np.empty(ids.shape[0], np.int64)
    m = 0
    for i in range(ids.shape[0]):
        if flags[ids[i]]:
            out[m] = i
            m += 1
    return out[:m].copy()


def _line_before(scan: Scan, slots: np.ndarray) -> np.ndarray:
    """The slot in the row before each of ``slots`` (the first row: the slot itself): for a
    spinning sensor the next beam up, whatever order the reader gave the rows in (readers give
    them top beam first: the row above); for a profiler the previous scan line of the stream."""
    rows, cols = scan.shape
    r, c = np.divmod(slots, cols)
    if isinstance(scan.sensor, SpinningSensor):
        down = np.argsort(-np.asarray(scan.sensor.altitude, dtype=np.float64), kind="stable")  # top first
        prev = np.empty(rows, np.int64)
        prev[down] = np.concatenate([down[:1], down[:-1]])
        return prev[r] * cols + c
    return np.where(r > 0, slots - cols, slots)


@njit(cache=True, nogil=True)
def group_medians(ids, values, groups):
    """``np.median(values[ids == g])`` for every ``g`` of ``groups`` (NaN for an empty group), in
    one counting sort. ``values`` float32: an even count takes the mean of the middle two in
    float32 arithmetic, as ``np.median`` does."""
    m = 0
    for g in groups:
        m = max(m, g)
    slot = np.full(m + 1, -1, np.int64)
    for i in range(groups.shape[0]):
        slot[groups[i]] = i
    count = np.zeros(groups.shape[0] + 1, np.int64)
    for k in ids:
        if k <= m and slot[k] >= 0:
            count[slot[k] + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    buf = np.empty(start[-1], values.dtype)
    for i in range(ids.shape[0]):
        k = ids[i]
        if k <= m and slot[k] >= 0:
            buf[fill[slot[k]]] = values[i]
            fill[slot[k]] += 1
    out = np.full(groups.shape[0], np.nan)
    for i in range(groups.shape[0]):
        v = np.sort(buf[start[i] : start[i + 1]])
        n = v.shape[0]
        if n == 0:
            continue
        if n % 2 == 1:
            out[i] = v[n // 2]
        else:
            out[i] = (v[n // 2 - 1] + v[n // 2]) / values.dtype.type(2)
    return out


@njit(cache=True, nogil=True)
def region_stats(regions, z, n, by_column):
    """Per region ``0..n`` of ``regions`` (rows, cols): lowest and highest ``z``, number of
    slots, and number of scan lines it spans (columns if ``by_column``, else rows); index 0 is
    left at (inf, -inf, 0, 0)."""
    R, C = regions.shape
    zmin = np.full(n + 1, np.inf)
    zmax = np.full(n + 1, -np.inf)
    size = np.zeros(n + 1, np.int64)
    n_lines = np.zeros(n + 1, np.int64)
    last = np.full(n + 1, -1, np.int64)
    outer, inner = (C, R) if by_column else (R, C)
    for a in range(outer):
        for b in range(inner):
            r, c = (b, a) if by_column else (a, b)
            k = regions[r, c]
            if k == 0:
                continue
            v = np.float64(z[r, c])
            zmin[k] = min(zmin[k], v)
            zmax[k] = max(zmax[k], v)
            size[k] += 1
            if last[k] != a:  # first slot of region k on line a
                last[k] = a
                n_lines[k] += 1
    return zmin, zmax, size, n_lines


def _polylines(regions: np.ndarray, ok: np.ndarray, line_index: np.ndarray, xyz: np.ndarray) -> list[np.ndarray]:
    """One polyline per accepted region: the mean point of each of its scan lines, in line order
    (float32 rows; regions in id order)."""
    mean, owner = polyline_means(regions, ok, line_index, xyz.reshape(-1, 3))
    if not len(owner):
        return []
    mean = mean.astype(np.float32)
    bounds = [0, *(np.flatnonzero(owner[1:] != owner[:-1]) + 1).tolist(), len(owner)]
    return [mean[a:b] for a, b in pairwise(bounds)]  # np.split's pieces, without its per-piece overhead


@njit(cache=True, nogil=True)
def polyline_means(regions, ok, line_index, xyz):
    """The points of :func:`_polylines`: for every region ``k`` of ``regions`` (rows, cols) with
    ``ok[k]`` and every scan line ``line_index[r, c]`` it touches, the mean of its slots' ``xyz``
    (flat, rows * cols x 3), summed in image order. Returns ``(mean (m, 3), owner (m,))``
    sorted by region, then line."""
    R, C = regions.shape
    m = 0
    for r in range(R):
        for c in range(C):
            k = regions[r, c]
            if k > 0 and ok[k]:
                m += 1
    key = np.empty(m, np.int64)
    slot = np.empty(m, np.int64)
    m = 0
    for r in range(R):
        for c in range(C):
            k = regions[r, c]
            if k > 0 and ok[k]:
                key[m] = (np.int64(k) << 20) + line_index[r, c]
                slot[m] = r * C + c
                m += 1
    order = np.argsort(key, kind="mergesort")  # stable: each line's slots stay in image order
    groups = 0
    for i in range(m):
        if i == 0 or key[order[i]] != key[order[i - 1]]:
            groups += 1
    mean = np.zeros((groups, 3))
    owner = np.empty(groups, np.int64)
    g = -1
    cnt = 0
    for i in range(m):
        j = order[i]
        if i == 0 or key[j] != key[order[i - 1]]:
            if g >= 0:
                for d in range(3):
                    mean[g, d] /= cnt
            g += 1
            owner[g] = key[j] >> 20
            cnt = 0
        s = slot[j]
        for d in range(3):
            mean[g, d] += np.float64(xyz[s, d])
        cnt += 1
    if g >= 0:
        for d in range(3):
            mean[g, d] /= cnt
    return mean, owner


def _line_index(scan: Scan) -> np.ndarray:
    """Scan line of every slot: the column for a spinning sensor, the row for a profiler."""
    rows, cols = scan.shape
    if isinstance(scan.sensor, SpinningSensor):
        return np.broadcast_to(np.arange(cols)[None, :], (rows, cols))
    return np.broadcast_to(np.arange(rows)[:, None], (rows, cols))
