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

import numpy as np
from numba import njit

from prc_slam.online import kernels as K
from prc_slam.online.coarse import CoarseResult, line_values
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
    for li in range(n_lines):
        pts = K.line_returns(lines[li], valid)
        m = pts.shape[0]
        first = 0
        if last_only:
            for k in range(m):
                if ground[pts[k]]:
                    first = k
        found = 0
        searching = False
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
            d = np.sqrt(xyz[s, 0] ** 2 + xyz[s, 1] ** 2 + xyz[s, 2] ** 2)
            far = 0.0
            for j in range(max(0, k - look_back), k):
                q = pts[j]
                far = max(far, np.sqrt(xyz[q, 0] ** 2 + xyz[q, 1] ** 2 + xyz[q, 2] ** 2))
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
    lines = coarse.lines
    pc = possible_curbs(
        xyz.reshape(-1, 3).astype(np.float64),
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
    order = np.argsort(scan.sensor.altitude, kind="stable") if wrap else np.arange(scan.shape[0])
    regions_o, n = prc_kernels.connected_components_within(
        np.ascontiguousarray(vertical[order]), np.ascontiguousarray(xyz[order], dtype=np.float64), p.max_gap, wrap
    )
    regions = np.empty_like(regions_o)
    regions[order] = regions_o
    if n == 0 or len(pc) == 0:
        return CurbResult(mask, [], possible)
    # region statistics, vectorised over the labelled slots
    lab = regions.ravel()
    sel = lab > 0
    ids = lab[sel]
    z = xyz[..., 2].ravel()[sel]
    zmin = np.full(n + 1, np.inf)
    zmax = np.full(n + 1, -np.inf)
    order = np.argsort(ids, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(ids[order]) != 0])
    present = ids[order][starts]
    zmin[present] = np.minimum.reduceat(z[order], starts)
    zmax[present] = np.maximum.reduceat(z[order], starts)
    has_pc = np.zeros(n + 1, dtype=bool)
    has_pc[regions.ravel()[pc]] = True
    line_of = _line_index(scan).ravel()[sel]
    pairs = np.unique(ids.astype(np.int64) * (1 << 20) + line_of)
    n_lines = np.bincount(pairs >> 20, minlength=n + 1)
    size = np.bincount(ids, minlength=n + 1)
    ok = has_pc & (zmax - zmin <= p.t_curb) & (zmax - zmin >= p.min_height)
    short = np.flatnonzero(ok & (n_lines < p.min_lines))
    if len(short):  # few scan lines: accept only with >= 3 points and a small median curvature
        curv = np.abs(np.diff(coarse.sv, axis=0, prepend=coarse.sv[:1])).ravel()[sel]
        for r in short:  # candidate regions only (a handful per frame)
            ok[r] = size[r] >= 3 and np.median(curv[ids == r]) <= p.max_curvature
    ok[0] = False
    mask = ok[regions]
    return CurbResult(mask, _polylines(regions, ok, _line_index(scan), xyz), possible)


def _polylines(regions: np.ndarray, ok: np.ndarray, line_index: np.ndarray, xyz: np.ndarray) -> list[np.ndarray]:
    """One polyline per accepted region: the mean point of each of its scan lines, in line order."""
    members = ok[regions] & (regions > 0)
    if not members.any():
        return []
    r = regions[members].astype(np.int64)
    key = r * (1 << 20) + line_index[members]
    uniq, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    pts = xyz[members].astype(np.float64)
    mean = np.stack([np.bincount(inv, weights=pts[:, c]) for c in range(3)], axis=1) / counts[:, None]
    owner = uniq >> 20
    cuts = np.flatnonzero(np.diff(owner)) + 1
    return [m.astype(np.float32) for m in np.split(mean, cuts)]


def _line_index(scan: Scan) -> np.ndarray:
    """Scan line of every slot: the column for a spinning sensor, the row for a profiler."""
    rows, cols = scan.shape
    if isinstance(scan.sensor, SpinningSensor):
        return np.broadcast_to(np.arange(cols)[None, :], (rows, cols))
    return np.broadcast_to(np.arange(rows)[:, None], (rows, cols))
