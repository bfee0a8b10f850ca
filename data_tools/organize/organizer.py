"""The organiser: any sweep of points (any order, any spinning sensor) -> a ``Scan`` range image.

PRC (Lehtola et al. 2019, Sec. III) is defined on the raw stream as a range image whose rows
are scan lines (one beam's sweep for a spinning multi-beam sensor) and whose columns run along
a line. Readers that only have a point cloud call :class:`Organizer` to rebuild that image,
with an exact map from every input point to its slot so that labels computed on the image go
back to every input point, in input order.

Rows (beams) come from, in this order of preference (``method="auto"``):

1. a ring / channel / laser-id field (any numbering; ids are put in rows by their median
   elevation, top beam first);
2. the point order, when it is consistent: *ring-major* (one beam's sweep after the other,
   detected as several azimuth revolutions along the order, either direction) is cut into
   rings where the azimuth restarts a revolution, the cut refined point by point by elevation;
   each ring is then matched to a beam by its median elevation, so missing or split rings do
   not shift the rows; *column-major* (all beams of one firing, then the next: one revolution
   along the order) takes its rows from the beam elevations (3.);
3. clustering of elevation angles into the sensor's beams: peaks of a fine elevation
   histogram. The beam table is estimated once per sequence (first sweep) and reused, so row
   ``r`` is the same beam in every frame.

Azimuths and elevations are measured about the sensor's spin axis: found on the first sweep
(:func:`estimate_spin_axis`: the axis about which the elevations bunch at the beams) and used when
it is clearly off the points' ``z`` (a sweep given in a vehicle frame or on a tilted mount's base);
the points are not moved, the sensor model's rays are turned back into their frame.

Columns come from the azimuth: direction detected from the point order (or the per-point
times), bin width ``2*pi/cols`` with ``cols`` from the sensor when known, else estimated from
the median azimuth step between consecutive points of a ring; every row's bin phase is
estimated too (beams with an azimuth offset, e.g. Ouster's, fall in the middle of their bins).

Every sweep is checked (rings found vs expected, share of points that share a slot, empty
rows). Out of range -> a warning logged on ``prc_slam.organize`` and counted in
``Scan.meta["organize"]``; a sweep that cannot be organised -> :class:`DataError` naming the
source. A collapse is never silent.

No-return input points (NaN/inf coordinates, or exactly at the origin): they keep their entry
in the input order, are counted (``nonfinite_points``), never reach PRC, and are represented
in the Scan as a zero row of ``Scan.cloud`` mapped to an empty slot (range 0), so
``Scan.per_point`` gives them label 0 (no_return) and ``Scan.points()`` stays finite.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from data_tools.errors import DataError
from prc_slam.prc.ground import levelling_rotation
from prc_slam.scan import Scan, SpinningSensor
from prc_slam.threads import in_threads

log = logging.getLogger("prc_slam.organize")

METHODS = ("auto", "ring", "order", "beams")

#: points farther than this (m) are no returns (a placeholder such as 3e38 for "no return", not a
#: measurement: it would otherwise form a ring of its own)
MAX_RANGE = 1e5

#: fewer returns than this share of the range image's slots: its rings or columns are implausible
#: (a spinning sweep fills most of them; a camera-FOV crop of 30 deg still fills 8 %)
MIN_OCCUPANCY = 0.03
TWO_PI = 2.0 * np.pi

#: cost (in beam gaps) of giving a run the row of the run before it in a ring-major sweep (a ring
#: cut in two), against one row further along the first sweep's ring order
RING_REUSE_COST = 0.5

#: columns per turn above which an estimate is refused (the finest spinning sensors: 0.05 deg, 7,200
#: a turn; a map tile's points, steps of micro-degrees seen from a corner, gave 360,391 and 16 s)
MAX_COLUMNS = 16384

#: share of points sharing a slot above which a sweep is reported (warning) / refused (error)
WARN_COLLISIONS = 0.12
MAX_COLLISIONS = 0.5
#: beams method: share of points within a quarter beam gap of their beam below which the
#: elevations show no beam structure (uniform elevations give ~0.5)
MIN_BEAM_CONCENTRATION = 0.65

#: :func:`estimate_spin_axis` searches this far (deg) from the points' z axis
SPIN_AXIS_MAX_TILT_DEG = 20.0
#: the points are organised about the spin axis found when it is at least this far from z (deg;
#: KITTI 00's own sweeps give 0.36, level sensors' 0-0.4; 2 deg already put 15 % of a 64-beam
#: sweep's points in another beam's slots) ...
SPIN_AXIS_MIN_TILT_DEG = 1.0
#: ... and its elevation histogram (0.1 deg bins) is this much sharper than about z (sum of squared
#: counts: 1.05 at a 1.2 deg tilt of a KITTI sweep, 1.13 at 3 deg, 1.9 at 15 deg; 1.00-1.03 for the
#: level sensors of the shared data)
SPIN_AXIS_MIN_GAIN = 1.04


@dataclass
class OrganizeReport:
    """Plausibility figures of one organised sweep (``Scan.meta["organize"]``)."""

    method: str
    rings: int
    expected_rings: int | None
    cols: int
    collisions_pct: float
    empty_rows: int
    nonfinite_points: int
    warnings: list[str] = field(default_factory=list)
    multi_returns: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "rings": int(self.rings),
            "expected_rings": None if self.expected_rings is None else int(self.expected_rings),
            "cols": int(self.cols),
            "collisions_pct": float(self.collisions_pct),
            "empty_rows": int(self.empty_rows),
            "nonfinite_points": int(self.nonfinite_points),
            "multi_returns": int(self.multi_returns),
            "warnings": list(self.warnings),
        }


class OrganizeSummary:
    """The organiser's reports over a run, for the metrics JSON (``"organize"`` key).

    ``add(scan.meta.get("organize"))`` per frame (frames without a report, e.g. from the
    simulator or an organised source, are counted as such); ``as_dict()`` gives
    ``{"frames", "methods", "rings": {min, median, max}, "expected_rings", "cols",
    "collisions_pct": {mean, max}, "empty_rows_max", "nonfinite_points", "warnings",
    "warning_messages"}`` (the first 20 messages)."""

    def __init__(self) -> None:
        self.reports: list[dict[str, Any]] = []
        self.unorganised = 0

    def add(self, report: dict[str, Any] | None) -> None:
        if report is None:
            self.unorganised += 1
        else:
            self.reports.append(report)

    def as_dict(self) -> dict[str, Any]:
        r = self.reports
        if not r:
            return {"frames": 0, "frames_without_report": self.unorganised, "warnings": 0}
        rings = np.array([x["rings"] for x in r])
        coll = np.array([x["collisions_pct"] for x in r])
        messages = [m for x in r for m in x["warnings"]]
        return {
            "frames": len(r),
            "frames_without_report": self.unorganised,
            "methods": sorted({x["method"] for x in r}),
            "rings": {"min": int(rings.min()), "median": float(np.median(rings)), "max": int(rings.max())},
            "expected_rings": r[-1]["expected_rings"],
            "cols": r[-1]["cols"],
            "collisions_pct": {"mean": float(coll.mean()), "max": float(coll.max())},
            "empty_rows_max": int(max(x["empty_rows"] for x in r)),
            "nonfinite_points": int(sum(x["nonfinite_points"] for x in r)),
            "warnings": len(messages),
            "warning_messages": messages[:20],
        }


# ----------------------------------------------------------------------------- numba kernels


@njit(cache=True, nogil=True, inline="always")
def _atan2(y, x):
    """atan2 by a degree-11 minimax polynomial (|error| < 2e-6 rad, far below a column)."""
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    if mx == 0.0:
        return 0.0
    a = min(ax, ay) / mx
    q = a * a
    r = (((((-0.0117212 * q + 0.05265332) * q - 0.11643287) * q + 0.19354346) * q - 0.33262347) * q + 0.99997726) * a
    if ay > ax:
        r = 1.5707963267948966 - r
    if x < 0.0:
        r = 3.141592653589793 - r
    if y < 0.0:
        r = -r
    return r


@njit(cache=True, nogil=True)
def _polar(xyz, offset, ok, rng, az, te, cloud, small=0.7853981633974483):
    """Per point: has a return (finite, not at the origin, nearer than :data:`MAX_RANGE`), range,
    azimuth (rad, (-pi, pi]) and the tangent of the beam
    elevation ``z / (rho - offset)``, ``offset`` being the horizontal distance of the beam
    origins from the sensor axis (Ouster: ``lidar_origin_to_beam_origin``; 0 for decoders
    that give points from one origin). Along the input order also: the share of azimuth
    steps between consecutive returns smaller than ``small`` and the signed sum of those
    steps (revolutions * 2 pi), which tell the point order. Writes into ``ok, rng, az, te``
    (work arrays reused from sweep to sweep: fresh ones cost page faults) and copies the
    points into ``cloud`` (float32, no-return rows zeroed)."""
    n = xyz.shape[0]
    prev = 0.0
    have = False
    steps = 0
    n_small = 0
    total = 0.0
    for i in range(n):
        x = float(xyz[i, 0])
        y = float(xyz[i, 1])
        z = float(xyz[i, 2])
        rho2 = x * x + y * y
        r2 = rho2 + z * z
        good = math.isfinite(r2) and r2 > 0.0 and r2 < MAX_RANGE * MAX_RANGE
        ok[i] = good
        if good:
            cloud[i, 0] = x
            cloud[i, 1] = y
            cloud[i, 2] = z
        else:
            cloud[i, 0] = 0.0
            cloud[i, 1] = 0.0
            cloud[i, 2] = 0.0
            rng[i] = 0.0
            az[i] = 0.0
            te[i] = 0.0
            continue
        rho = math.sqrt(rho2)
        rng[i] = math.sqrt(r2)
        a = _atan2(y, x)
        az[i] = a
        h = rho - offset
        te[i] = z / h if h > 1e-6 else (1e6 if z > 0 else -1e6)
        if have:
            d = a - prev
            if d > np.pi:
                d -= 2.0 * np.pi
            elif d <= -np.pi:
                d += 2.0 * np.pi
            steps += 1
            if abs(d) < small:
                n_small += 1
                total += d
        prev = a
        have = True
    return n_small / max(steps, 1), total


@njit(cache=True, nogil=True)
def _wrap(a):
    while a > np.pi:
        a -= 2.0 * np.pi
    while a <= -np.pi:
        a += 2.0 * np.pi
    return a


@njit(cache=True, nogil=True)
def _ring_runs(az, ok, s, jitter, over):
    """Cut a ring-major sequence into runs (candidate rings) where the azimuth restarts.

    Walking the points in input order, each ring's progress ``P`` (azimuth travelled in
    direction ``s`` since the ring's first point) grows to about 2 pi. A step of ``f``
    (forward, in ``[0, 2 pi)``; backward steps smaller than ``jitter`` count as negative)
    starts a new run when ``P + f`` exceeds ``2 pi - over``: the point has come back to where
    the ring began. Returns the run id of every point (-1 for no-return points)."""
    n = az.shape[0]
    run = np.full(n, -1, np.int64)
    cur = -1
    prog = 0.0
    pmin = 0.0
    prev = -1
    for i in range(n):
        if not ok[i]:
            continue
        if prev < 0:
            cur = 0
            prog = 0.0
            pmin = 0.0
        else:
            f = s * (az[i] - az[prev])
            f = f - 2.0 * np.pi * math.floor(f / (2.0 * np.pi))  # [0, 2 pi)
            if f > 2.0 * np.pi - jitter:
                f -= 2.0 * np.pi
            # progress is measured from the ring's earliest azimuth (jitter at its start)
            if prog + f - pmin > 2.0 * np.pi - over:
                cur += 1
                prog = 0.0
                pmin = 0.0
            else:
                prog += f
                pmin = min(pmin, prog)
        run[i] = cur
        prev = i
    return run


@njit(cache=True, nogil=True)
def _ring_runs_cut(az, ok, s, cut, jitter, run):
    """Second pass of the ring-major cut: with the sweep's cut azimuth known, a ring ends
    where the azimuth passes the cut (``u``, the angle from the cut in direction ``s``, drops
    by more than pi after the ring has travelled more than ``jitter``: an upper ring may see
    only one building) or jumps back by more than ``jitter`` (the ring ended early, the next
    one starts again near the cut). Writes the
    run of every point into ``run`` (-1 for no-return points); returns the number of runs."""
    n = az.shape[0]
    cur = -1
    prog = 0.0
    up = 0.0
    for i in range(n):
        if not ok[i]:
            run[i] = -1
            continue
        u = s * (az[i] - cut)
        # into [0, 2 pi): az and cut lie in (-pi, pi], so u is within one turn of it
        if u < 0.0:
            u += 2.0 * np.pi
        elif u >= 2.0 * np.pi:
            u -= 2.0 * np.pi
        if u < 0.0 or u >= 2.0 * np.pi:
            u = u - 2.0 * np.pi * math.floor(u / (2.0 * np.pi))
        if cur < 0:
            cur = 0
            prog = 0.0
        else:
            drop = up - u
            if (drop > np.pi and prog > jitter) or (jitter < drop <= np.pi):
                cur += 1
                prog = 0.0
            else:
                f = u - up
                if f < -np.pi:
                    f += 2.0 * np.pi
                elif f > np.pi:
                    f -= 2.0 * np.pi
                prog += f
        run[i] = cur
        up = u
    return cur + 1


@njit(cache=True, nogil=True)
def _run_bounds(run, n_runs):
    """First and one-past-last input index of each run (runs are contiguous in the order)."""
    lo = np.full(n_runs, -1, np.int64)
    hi = np.full(n_runs, -1, np.int64)
    for i in range(run.shape[0]):
        k = run[i]
        if k < 0:
            continue
        if lo[k] < 0:
            lo[k] = i
        hi[k] = i + 1
    return lo, hi


@njit(cache=True, nogil=True)
def _run_medians(te, ok, lo, hi, sample=255):
    """Median tangent-of-elevation of each run (of at most ``sample`` points spread evenly
    over the run) and its number of points."""
    m = lo.shape[0]
    med = np.full(m, np.nan)
    cnt = np.zeros(m, np.int64)
    buf = np.empty(sample + 1)
    for k in range(m):
        if lo[k] < 0:
            continue
        c = 0
        for i in range(lo[k], hi[k]):
            if ok[i]:
                c += 1
        cnt[k] = c
        if c == 0:
            continue
        stride = max(1, (hi[k] - lo[k]) // sample)
        b = 0
        for i in range(lo[k], hi[k], stride):
            if ok[i] and b < sample + 1:
                buf[b] = te[i]
                b += 1
        if b == 0:
            for i in range(lo[k], hi[k]):
                if ok[i]:
                    buf[0] = te[i]
                    b = 1
                    break
        med[k] = np.median(buf[:b])
    return med, cnt


@njit(cache=True, nogil=True)
def _run_spread(te, ok, lo, hi, med):
    """Median absolute deviation of the tangent of elevation within each run."""
    m = lo.shape[0]
    out = np.full(m, np.nan)
    for k in range(m):
        if lo[k] < 0 or not np.isfinite(med[k]):
            continue
        buf = np.empty(hi[k] - lo[k])
        c = 0
        for i in range(lo[k], hi[k]):
            if ok[i]:
                buf[c] = abs(te[i] - med[k])
                c += 1
        if c:
            out[k] = np.median(buf[:c])
    return out


@njit(cache=True, nogil=True)
def _refine_cuts(te, ok, run, lo, hi, row_of_run, beam_te, window, refine, row):
    """Row of every point (-1 for no-return points); with ``refine``, each cut between
    consecutive runs of different beams moved, within ``window`` points either side, to the
    split that puts the most points with the beam they are nearer in elevation (ties: the
    coarse cut).

    The azimuth alone leaves a cut ambiguous where the next ring starts a little behind the
    previous one's end (beam azimuth offsets) or a ring's first returns are missing; the
    elevation settles it when the beams' elevations are clean (the caller checks the spread
    within rings; not so for beams with vertical offsets such as the HDL-64E's). Writes
    into ``row``."""
    n = te.shape[0]
    for i in range(n):
        row[i] = row_of_run[run[i]] if ok[i] else -1
    if not refine:
        return row
    m = lo.shape[0]
    for k in range(m - 1):
        if lo[k] < 0 or lo[k + 1] < 0:
            continue
        ra = row_of_run[k]
        rb = row_of_run[k + 1]
        if ra == rb:
            continue
        ta = beam_te[ra]
        tb = beam_te[rb]
        cut = lo[k + 1]
        a = max(lo[k] + 1, cut - window)
        b = min(hi[k + 1] - 1, cut + window)
        score = 0
        best = -1
        best_j = cut
        for j in range(a, b + 1):
            if j > a:
                i = j - 1
                if ok[i]:
                    if abs(te[i] - ta) < abs(te[i] - tb):
                        score += 1
                    else:
                        score -= 1
            if score > best or (score == best and abs(j - cut) < abs(best_j - cut)):
                best = score
                best_j = j
        for i in range(a, b):
            if ok[i]:
                row[i] = ra if i < best_j else rb
    return row


@njit(cache=True, nogil=True)
def _nearest_beam(te, ok, bounds, row):
    """Row of each point: the beam whose elevation interval (between mid-points, in tangent
    space, ``bounds`` descending) holds the point, i.e. the number of bounds at or above it.
    -1 for no-return points. Writes into ``row``.

    A table over the bounds' span (bins finer than the narrowest beam interval) gives each
    point a row at most one or two steps from its own, which the exact comparisons then reach."""
    n = te.shape[0]
    nb = bounds.shape[0] + 1
    if nb == 1:
        for i in range(n):
            row[i] = 0 if ok[i] else -1
        return row
    lo = bounds[nb - 2]
    hi = bounds[0]
    gap = hi - lo
    for k in range(nb - 2):
        gap = min(gap, bounds[k] - bounds[k + 1])
    bins = int(min(max(4.0 * (hi - lo) / max(gap, 1e-12), 1.0), 65536.0))
    scale = bins / max(hi - lo, 1e-12)
    lut = np.empty(bins + 1, np.int64)
    r = nb - 1  # rows for t at the bins' lower edges, ascending t: falling rows
    for j in range(bins + 1):
        t = lo + j / scale
        while r > 0 and bounds[r - 1] < t:
            r -= 1
        lut[j] = r
    for i in range(n):
        if not ok[i]:
            row[i] = -1
            continue
        t = te[i]
        u = (t - lo) * scale
        j = 0 if u <= 0.0 else (bins if u >= bins else int(u))
        r = lut[j]
        while r < nb - 1 and bounds[r] >= t:
            r += 1
        while r > 0 and bounds[r - 1] < t:
            r -= 1
        row[i] = r
    return row


@njit(cache=True, nogil=True)
def _align_runs(run_ang, beam_ang, gap, reuse):
    """The rings of a ring-major sweep matched to the ring order of the sequence's first sweep.

    ``run_ang``: median elevation of each run (candidate ring) in input order; ``beam_ang``: the
    elevations of the first sweep's rings in that sweep's order. Each run takes one entry of the
    order, never an earlier one than the run before it (rings come in the driver's order; rings
    without returns are skipped at no cost), the same one again (a ring cut in two) at ``reuse``
    gaps. Minimises the sum of ``|run - beam| / gap`` by dynamic programming; returns the entry
    of each run and the mean cost per run."""
    m = run_ang.shape[0]
    n = beam_ang.shape[0]
    big = 1e300
    f = np.full((m, n), big)
    back = np.full((m, n), -1, np.int64)
    for j in range(n):
        f[0, j] = abs(run_ang[0] - beam_ang[j]) / gap
    for i in range(1, m):
        best = big  # min of f[i - 1, :j]
        arg = -1
        for j in range(n):
            c = abs(run_ang[i] - beam_ang[j]) / gap
            stay = f[i - 1, j] + reuse
            if best <= stay:
                f[i, j] = best + c
                back[i, j] = arg
            else:
                f[i, j] = stay + c
                back[i, j] = j
            if f[i - 1, j] < best:
                best = f[i - 1, j]
                arg = j
    out = np.empty(m, np.int64)
    j = 0
    for k in range(1, n):
        if f[m - 1, k] < f[m - 1, j]:
            j = k
    total = f[m - 1, j]
    for i in range(m - 1, -1, -1):
        out[i] = j
        j = back[i, j]
    return out, total / max(m, 1)


@njit(cache=True, nogil=True)
def _row_steps(az, row, rows, max_step):
    """Azimuth steps between consecutive points of the same row (input order), in (0, max_step)."""
    n = az.shape[0]
    last = np.full(rows, -1, np.int64)
    out = np.empty(n)
    c = 0
    for i in range(n):
        r = row[i]
        if r < 0:
            continue
        j = last[r]
        if j >= 0:
            d = abs(_wrap(az[i] - az[j]))
            if d > 1e-7 and d < max_step:
                out[c] = d
                c += 1
        last[r] = i
    return out[:c]


@njit(cache=True, nogil=True)
def _row_phase(az, row, rows, a0, s, inv_step):
    """Circular mean (over each row's points) of the fractional column position, and the
    mean resultant length (1 = every point at the same phase)."""
    sx = np.zeros(rows)
    sy = np.zeros(rows)
    cnt = np.zeros(rows)
    for i in range(az.shape[0]):
        r = row[i]
        if r < 0:
            continue
        u = s * (az[i] - a0) * inv_step
        f = u - math.floor(u)
        sx[r] += math.cos(2.0 * np.pi * f)
        sy[r] += math.sin(2.0 * np.pi * f)
        cnt[r] += 1
    phase = np.zeros(rows)
    strength = np.zeros(rows)
    for r in range(rows):
        if cnt[r] > 0:
            p = math.atan2(sy[r], sx[r]) / (2.0 * np.pi)
            phase[r] = p - math.floor(p)
            strength[r] = math.sqrt(sx[r] ** 2 + sy[r] ** 2) / cnt[r]
    return phase, strength


@njit(cache=True, nogil=True)
def _scatter(az, rng, row, a0, s, inv_step, phase, rows, cols, rep):
    """Slot of every point and the nearest point (representative) of every slot.

    Returns ``point_slot`` (-1 for no-return points), ``representative`` (-1 for empty
    slots), points per row, the number of points sharing a slot with another, and how many of
    those are further returns of the same firing (the same azimuth to 1 % of a column: dual
    or multiple returns, which share their slot by nature). ``rep`` is a work array of
    ``rows * cols`` entries."""
    n = az.shape[0]
    slot = np.empty(n, np.int64)
    rep[:] = -1
    per_row = np.zeros(rows, np.int64)
    collisions = 0
    multi = 0
    same = 0.01 / inv_step
    # the column of every point, without branches (the loop vectorises)
    for i in range(n):
        u = s * (az[i] - a0) * inv_step - phase[max(row[i], 0)] + 0.5
        c = int(math.floor(u))  # noqa: RUF046 (numba: explicit int)
        # u lies within about one turn of [0, cols): a subtraction spares the integer modulo
        c = c + cols if c < 0 else c
        c = c - cols if c >= cols else c
        slot[i] = c
    for i in range(n):
        r = row[i]
        if r < 0:
            slot[i] = -1
            continue
        c = slot[i]
        if c < 0 or c >= cols:
            c %= cols
        k = r * cols + c
        slot[i] = k
        per_row[r] += 1
        j = rep[k]
        if j < 0:
            rep[k] = i
        else:
            collisions += 1
            if abs(_wrap(az[i] - az[j])) < same:
                multi += 1
            if rng[i] < rng[j]:
                rep[k] = i
    return slot, rep, per_row, collisions, multi


@njit(cache=True, nogil=True)
def _gather(rep, src, out):
    """``out[k] = src[rep[k]]`` for occupied slots (``rep[k] >= 0``), 0 elsewhere."""
    for k in range(rep.shape[0]):
        j = rep[k]
        out[k] = src[j] if j >= 0 else 0
    return out


@njit(cache=True, nogil=True)
def _fill_slots(rep, rng, xyz):
    """Range and coordinates of every slot's representative (zeros for empty slots)."""
    size = rep.shape[0]
    ranges = np.empty(size, np.float32)
    out = np.empty((size, 3), np.float32)
    _fill_slots_into(rep, rng, xyz, ranges, out, 0, size)
    return ranges, out


@njit(cache=True, nogil=True)
def _fill_slots_into(rep, rng, xyz, ranges, out, lo, hi):
    """:func:`_fill_slots` for slots ``lo..hi-1``, written into ``ranges, out``."""
    for k in range(lo, hi):
        j = rep[k]
        if j >= 0:
            ranges[k] = rng[j]
            out[k, 0] = xyz[j, 0]
            out[k, 1] = xyz[j, 1]
            out[k, 2] = xyz[j, 2]
        else:
            ranges[k] = 0.0
            out[k, 0] = 0.0
            out[k, 1] = 0.0
            out[k, 2] = 0.0


@njit(cache=True, nogil=True)
def _slot_times_kernel(times, rep, rows, cols):
    """Time of every slot's representative, and the mean time of each column's points; empty
    slots get their column's mean (columns without points are flagged in ``known``)."""
    t = np.empty(rows * cols)
    sums = np.zeros(cols)
    cnt = np.zeros(cols, np.int64)
    for k in range(rows * cols):
        j = rep[k]
        if j >= 0:
            t[k] = times[j]
            sums[k % cols] += times[j]
            cnt[k % cols] += 1
    col_t = np.zeros(cols)
    known = cnt > 0
    for c in range(cols):
        if cnt[c] > 0:
            col_t[c] = sums[c] / cnt[c]
    for k in range(rows * cols):
        if rep[k] < 0:
            t[k] = col_t[k % cols]
    return t, col_t, known


@njit(cache=True, nogil=True)
def _fill_empty_times(t, rep, col_t, rows, cols):
    for k in range(rows * cols):
        if rep[k] < 0:
            t[k] = col_t[k % cols]
    return t


# ----------------------------------------------------------------------------- beam tables


def _nanmedian_rows(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=1)``, NaN for rows without a finite value and no warning about them."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice encountered": a row without returns
        return np.nanmedian(a, axis=1)


def _beam_bounds(beam_te: np.ndarray) -> np.ndarray:
    """Interval bounds (tangent space, descending) between consecutive beams (sorted top first),
    at the mid-angle between them."""
    ang = np.arctan(beam_te)
    return np.tan(0.5 * (ang[:-1] + ang[1:]))


def estimate_beams(
    te: np.ndarray, rng: np.ndarray, expected: int | None = None, resolution_deg: float = 0.02, near: float = 0.3
) -> tuple[np.ndarray, float]:
    """Beam elevations (as tangents, top beam first) from the peaks of an elevation histogram.

    ``te`` should be corrected for the beam origin offset (:func:`estimate_beam_offset`);
    points nearer than ``near`` metres are left out (the lowest beams of a sensor on a car
    may only see the ground within a few metres, so no more is dropped). Returns the table
    and its *concentration*: the share of points within a quarter of the local beam gap of
    their beam (near 1 for a multi-beam sensor, about 0.5 for elevations without beam
    structure).
    """
    el = np.degrees(np.arctan(te))
    use = el[rng >= near] if (rng >= near).sum() > 0.5 * len(rng) else el
    nb = round(180.0 / resolution_deg)
    hist, edges = np.histogram(use, bins=nb, range=(-90.0, 90.0))
    kernel = np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 9.0
    h = np.convolve(hist.astype(np.float64), kernel, mode="same")
    w = 3  # a peak is the maximum of +-3 bins (0.06 deg): beams closer than that are one beam
    pad = np.pad(h, w, constant_values=-1.0)
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * w + 1)
    is_peak = (h > 0) & (h >= win.max(axis=1))
    # of a flat top keep the first bin only
    is_peak[1:] &= ~(is_peak[:-1] & (h[1:] == h[:-1]))
    idx = np.flatnonzero(is_peak)
    if len(idx) == 0:
        return np.zeros(0), 0.0
    height = h[idx]
    top = np.sort(height)[::-1][: max(1, expected or 16)]
    keep = height >= max(0.5, 0.05 * float(np.median(top)))
    idx = idx[keep]
    if expected is not None and len(idx) > expected:
        idx = np.sort(idx[np.argsort(h[idx])[::-1][:expected]])
    centres = 0.5 * (edges[idx] + edges[idx + 1])
    # refine each peak to the mean elevation of the points within +-2 bins
    beams = np.sort(centres)[::-1]
    beam_te = np.tan(np.radians(beams))
    conc = beam_concentration(te, beam_te)
    return beam_te, conc


def estimate_beam_offset(
    xyz: np.ndarray, max_offset: float = 0.1, samples: int = 20000, rotation: np.ndarray | None = None
) -> float:
    """Horizontal distance (m) of the beam origins from the sensor axis, from the data.

    A beam leaving the axis at ``n`` metres puts its points at elevation
    ``atan(z / (rho - n))`` from the sensor origin, so near points of one beam spread in
    elevation unless ``n`` is known. The estimate is the ``n`` (1 mm steps, ``|n| <=
    max_offset``) that makes the elevation histogram sharpest (largest sum of squared counts).
    0 for decoders whose points come from one origin. ``rotation``: into the spin frame first.
    """
    xyz = np.asarray(xyz)
    idx = np.flatnonzero(np.isfinite(xyz).all(axis=1))
    if len(idx) > samples:
        idx = idx[np.random.default_rng(0).choice(len(idx), samples, replace=False)]
    pts = xyz[idx].astype(np.float64)  # the sampled finite points only
    if rotation is not None:
        pts = pts @ np.asarray(rotation).T
    rho = np.hypot(pts[:, 0], pts[:, 1])
    keep = rho > 2 * max_offset
    z, rho = pts[keep, 2], rho[keep]
    if len(z) < 100:
        return 0.0

    kernel = np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2)

    def sharpness(offsets: np.ndarray) -> np.ndarray:  # histogram at 0.005 deg, smoothed over sigma 0.01 deg
        out = np.empty(len(offsets))
        in_threads(lambda lo, hi: _sharpness_of(z, rho, offsets, kernel, out, lo, hi), len(offsets), min_chunk=1)
        return out

    coarse = np.arange(-max_offset, max_offset + 1e-9, 0.005)
    scores = sharpness(coarse)
    n0 = float(coarse[int(np.argmax(scores))])
    fine = np.arange(n0 - 0.005, n0 + 0.0051, 0.001)
    scores_f = sharpness(np.append(fine, 0.0))
    best = float(fine[int(np.argmax(scores_f[:-1]))])
    # only a clear gain over no offset counts
    return best if scores_f[:-1].max() > 1.05 * scores_f[-1] else 0.0


#: 0.005 deg bins over [-90, 90] deg (the elevation histogram of the beam-offset search)
ELEVATION_BINS = 36000


@njit(cache=True, nogil=True)
def _sharpness_of(z, rho, offsets, kernel, out, lo, hi):
    """:func:`_elevation_sharpness` for the offsets ``lo..hi - 1`` into ``out`` (one histogram
    and one bin array for all of them)."""
    half = kernel.shape[0] // 2
    h = np.zeros(ELEVATION_BINS + 2 * half)  # padded: the kernel may reach past both ends
    u = np.empty(z.shape[0])
    for i in range(lo, hi):
        out[i] = _elevation_sharpness(z, rho, offsets[i], kernel, h, u)


@njit(cache=True, nogil=True)
def _elevation_sharpness(z, rho, n, kernel, h, u):
    """Sharpness of the elevation histogram with the beams ``n`` metres off the axis: elevations
    ``atan(z / (rho - n))`` in 0.005 deg bins over (-90, 90), smoothed by ``kernel`` (centred) so
    that bin edges do not count, summed squared. Only the bins the points reach (and the
    kernel's reach around them) are visited. ``h`` (zeros, ``ELEVATION_BINS`` + the kernel's
    width) and ``u`` (one entry per point) are work arrays; ``h`` is left zeroed.

    The bins are first taken from :func:`_atan2` (within 2e-6 rad, 2 % of a bin, without
    libm's arctan); the points within 5 % of a bin's edge are binned again with ``arctan``, so
    every bin is the one ``arctan`` gives."""
    bins = ELEVATION_BINS
    half = kernel.shape[0] // 2
    scale = 180.0 / np.pi / 0.005
    for i in range(z.shape[0]):
        u[i] = _atan2(z[i], rho[i] - n) * scale + 90.0 / 0.005
    lo = bins
    hi = -1
    for i in range(z.shape[0]):
        b = math.floor(u[i])
        if u[i] - b < 0.05 or u[i] - b > 0.95:
            el = np.degrees(np.arctan(z[i] / (rho[i] - n)))
            b = math.floor((el + 90.0) / 0.005)
            if b == bins and el <= 90.0:  # the last bin is closed, as np.histogram's
                b = bins - 1
        if 0 <= b < bins:
            h[int(b) + half] += 1.0
            lo = min(lo, int(b))
            hi = max(hi, int(b))
    total = 0.0
    for j in range(max(lo - half, 0), min(hi + half, bins - 1) + 1):
        v = 0.0
        for t in range(kernel.shape[0]):
            v += kernel[t] * h[j + t]
        total += v * v
    if hi >= lo:
        h[lo + half : hi + half + 1] = 0.0
    return total


@njit(cache=True, nogil=True)
def _axis_sharpness(u, axes, bin_rad, out):
    """For each axis (unit rows of ``axes``): the sharpness of the histogram of ``u . axis`` (the
    sines of the elevations of the unit vectors ``u`` about that axis) in bins of ``bin_rad``,
    smoothed by (1, 2, 1) / 4 so that bin edges do not count, summed squared."""
    inv_bin = 1.0 / bin_rad
    nb = int(2.0 * inv_bin) + 5  # sines in [-1, 1] (rounding may step past): bins 1 .. nb - 2
    h = np.zeros(nb)
    for k in range(axes.shape[0]):
        lo, hi = nb, -1
        for i in range(u.shape[0]):
            s = u[i, 0] * axes[k, 0] + u[i, 1] * axes[k, 1] + u[i, 2] * axes[k, 2]
            b = int((min(max(s, -1.0), 1.0) + 1.0) * inv_bin) + 2
            h[b] += 1.0
            lo = min(lo, b)
            hi = max(hi, b)
        total = 0.0
        for j in range(lo - 1, hi + 2):
            v = 0.25 * h[j - 1] + 0.5 * h[j] + 0.25 * h[j + 1]
            total += v * v
        h[lo : hi + 1] = 0.0
        out[k] = total


def _axes_around(axis: np.ndarray, half_deg: float, step_deg: float) -> np.ndarray:
    """Unit axes on a square grid of ``step_deg`` within ``half_deg`` of ``axis`` (in tangent-plane
    angles; ``axis`` itself at the centre)."""
    t1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(axis, t1)
    k = round(half_deg / step_deg)
    g = np.tan(np.radians(step_deg * np.arange(-k, k + 1)))
    dx, dy = (a.ravel() for a in np.meshgrid(g, g))
    v = axis[None, :] + dx[:, None] * t1[None, :] + dy[:, None] * t2[None, :]
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def estimate_spin_axis(
    xyz: np.ndarray, max_tilt_deg: float = SPIN_AXIS_MAX_TILT_DEG, samples: int = 20000
) -> tuple[np.ndarray, float, float]:
    """The axis a multi-beam sensor spun about, from one sweep given in a frame within
    ``max_tilt_deg`` of it (a vehicle frame, a tilted mount's base).

    Each beam sweeps a cone about the spin axis, so about the right axis the elevations of the
    points bunch at the beams' elevations and the elevation histogram is sharpest (largest sum
    of squared counts, as :func:`estimate_beam_offset` judges an offset); about an axis tilted by
    ``t`` every beam smears over +-``t``. Searched on a grid in four steps (1 deg steps over the
    whole range, ``z`` itself on the grid, on 4,000 points; then 0.25, 0.05 and 0.01 deg around
    the best on up to 20,000), the points nearer than 3 m left out (beam-origin offsets smear
    those); not at all when the sweep is sharper about ``z`` than about the eight axes 1 deg
    around it (a level sweep: ``z`` is returned at once). Not a search over every direction: a
    cloud with many points on one plane through the sensor (the scan columns of a solid-state
    sensor such as the AT128) is sharpest about that plane's normal, far from any spin axis.

    Returns
    -------
    axis : ndarray (3,)
        Unit spin axis in the points' frame (``z`` when nothing better is found).
    tilt_deg : float
        Its angle from ``z``; ``nan`` when the best axis of the first step lies on the edge of
        the range (the spin axis is likely farther off: nothing is concluded).
    gain : float
        Sharpness about ``axis`` over that about ``z`` (0.1 deg bins; 1 when they are the same).
    """
    z = np.array([0.0, 0.0, 1.0])
    xyz = np.asarray(xyz)
    pick = np.random.default_rng(0).permutation(len(xyz))[: 3 * samples]  # in random order: u[:n] is a random subset
    p = xyz[pick].astype(np.float64)
    r = np.linalg.norm(p, axis=1)
    keep = np.flatnonzero(np.isfinite(r) & (r > 3.0) & (r < MAX_RANGE))[:samples]
    if len(keep) < 500:
        return z, 0.0, 1.0
    u = p[keep] / r[keep, None]
    # the common case first: a level sweep is sharper about z than about the 8 axes 1 deg around
    ring = _axes_around(z, 1.0, 1.0)
    score = np.empty(len(ring))
    _axis_sharpness(u, ring, np.radians(0.1), score)
    if score[4] > score.max(initial=0.0, where=np.arange(len(ring)) != 4):  # (4: z itself)
        return z, 0.0, 1.0
    axis = z
    for k, (half, step, bin_deg, n) in enumerate(
        ((max_tilt_deg, 1.0, 0.2, 4000), (1.5, 0.25, 0.1, 8000), (0.3, 0.05, 0.05, None), (0.06, 0.01, 0.02, None))
    ):
        cand = _axes_around(axis, half, step)
        score = np.empty(len(cand))
        _axis_sharpness(u[:n], cand, np.radians(bin_deg), score)
        i = int(np.argmax(score))
        side = round(np.sqrt(len(cand)))
        if k == 0 and (i // side in (0, side - 1) or i % side in (0, side - 1)):
            return cand[i], float("nan"), 1.0
        axis = cand[i]
    both = np.empty(2)
    _axis_sharpness(u, np.stack([z, axis]), np.radians(0.1), both)
    tilt = float(np.degrees(np.arccos(np.clip(axis[2], -1.0, 1.0))))
    return axis, tilt, float(both[1] / both[0]) if both[0] > 0 else 1.0


def beam_concentration(te: np.ndarray, beam_te: np.ndarray) -> float:
    """Share of points within a quarter of the local beam gap (in angle) of their nearest beam."""
    if len(beam_te) < 2 or len(te) == 0:
        return 1.0 if len(beam_te) == 1 else 0.0
    ang = np.arctan(beam_te)  # descending
    el = np.arctan(te)
    bounds = _beam_bounds(beam_te)
    row = _nearest_beam(te, np.ones(len(te), bool), bounds, np.empty(len(te), np.int64))
    gaps = np.abs(np.diff(ang))
    local = np.empty(len(ang))
    local[0], local[-1] = gaps[0], gaps[-1]
    local[1:-1] = np.minimum(gaps[:-1], gaps[1:])
    inside = np.abs(el - ang[row]) <= 0.25 * local[row]
    return float(inside.mean())


# ----------------------------------------------------------------------------- the organiser


_warm = False


def warm_up() -> None:
    """Load (or compile) the organiser's kernels once per process, when the first organiser is
    made: otherwise the first sweep of a run pays for it (0.2-0.6 s), and its organising time is
    charged to PRC (``Scan.meta["organize_seconds"]``)."""
    global _warm
    if _warm:
        return
    _warm = True
    elev = np.radians(np.linspace(-15.0, 15.0, 16))
    az = np.radians(np.arange(0.0, 360.0, 1.0))
    e, a = np.meshgrid(elev, az, indexing="ij")  # ring-major
    r = 10.0 + np.cos(3 * a)
    xyz = np.stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a), r * np.sin(e)], axis=-1)
    ring = np.repeat(np.arange(16), len(az))
    times = np.tile(np.linspace(0.0, 0.1, len(az), endpoint=False), 16)
    points = xyz.reshape(-1, 3)
    n = len(points)
    order = np.random.default_rng(0).permutation(n)
    xyzi = np.ones((n, 4), np.float32)  # a KITTI bin: x, y, z, remission
    xyzi[:, :3] = points
    as_read = {  # with its label file, as the reader gives them (views of the bin's columns)
        "xyz": xyzi[:, :3],
        "intensity": xyzi[:, 3],
        "gt_point_labels": np.zeros(n, np.uint8),
        "gt_point_instance": np.zeros(n, np.uint32),
    }
    for kwargs in (
        {"xyz": points},
        {"xyz": points, "ring": ring, "times": times},
        {"xyz": xyz.transpose(1, 0, 2).reshape(-1, 3)},
        {"xyz": points[order]},
        as_read,
    ):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                org = Organizer(source_name="warm-up", find_spin_axis=False)  # (searched once below)
                for _ in range(2):  # later sweeps of a sequence take other kernels (ring order)
                    org.scan(**kwargs)
        except DataError:
            pass
    estimate_spin_axis(points[:1000])


class Organizer:
    """Organises the sweeps of one sequence into range images (one instance per sequence).

    Parameters
    ----------
    rows, cols : int, optional
        Beams and columns of the sensor when known; otherwise estimated on the first sweep
        (rows: beams found; cols: from the median azimuth step along a ring) and kept.
    altitude : array, optional
        Beam elevations (rad) when known; sets ``rows`` and the beam table.
    method : {"auto", "ring", "order", "beams"}
        ``auto`` uses a ring field when given, else the point order when it is consistent,
        else elevation clustering. The others force one way (``ring`` needs the field).
    source_name : str
        Name of the sequence, for messages.
    sweep_period : float
        Duration of one sweep (s), for per-column times when no per-point times are given.
    spin : {None, "cw", "ccw"}
        The sensor's direction of rotation seen from above (``cw``: azimuth falls in time),
        when the source's convention fixes it (KITTI: ``cw``); otherwise taken from per-point
        times, else from the point order (the order is taken as the firing order).
    start_azimuth : float, optional
        Azimuth (rad) where a sweep starts, when the source's convention fixes it (KITTI: 0);
        otherwise the azimuth of the first point in time (or in order).
    find_spin_axis : bool
        On the first sweep, look for the sensor's spin axis (:func:`estimate_spin_axis`; not with
        a known beam table, whose decoder gives sensor-frame points): points given in a frame
        tilted from it (a vehicle frame) are organised about it, the sensor model's rays turned
        back into the points' frame (``SpinningSensor.mount``), and the tilt said once.

    One instance per sequence and per thread: the beam table, column count, cut azimuth and
    work arrays are kept from sweep to sweep.

    Columns run in firing order from the sweep's start: column ``c`` holds the azimuths
    ``start + direction * (c + phase_r +- 0.5) * 2 pi / cols``; without per-point times, column
    ``c`` is stamped ``frame_time + (c + 0.5) / cols * sweep_period`` only when ``spin`` is given
    (the source fixes its time convention); otherwise the Scan carries no times.
    """

    def __init__(
        self,
        rows: int | None = None,
        cols: int | None = None,
        altitude: np.ndarray | None = None,
        method: str = "auto",
        source_name: str = "seq",
        sweep_period: float = 0.1,
        spin: str | None = None,
        start_azimuth: float | None = None,
        find_spin_axis: bool = True,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"organiser method {method!r}; choose from {METHODS}")
        if spin not in (None, "cw", "ccw"):
            raise ValueError(f"organiser spin {spin!r}; choose from None, 'cw', 'ccw'")
        self.method = method
        self.source_name = source_name
        self.sweep_period = float(sweep_period)
        self.spin = spin
        self.expected_rows = int(rows) if rows is not None else None
        self.cols = int(cols) if cols is not None else None
        self.beam_te: np.ndarray | None = None
        if altitude is not None:
            alt = np.asarray(altitude, dtype=np.float64)
            if alt.ndim != 1 or len(alt) == 0 or not np.isfinite(alt).all():
                raise ValueError("altitude must be a non-empty 1-D array of finite angles (rad)")
            self.beam_te = np.sort(np.tan(alt))[::-1]
            self.expected_rows = len(alt)
        self.ring_ids: np.ndarray | None = None  # ring field values, in row order
        self.direction: int | None = None if spin is None else (-1 if spin == "cw" else 1)
        self.a0: float | None = None if start_azimuth is None else float(start_azimuth)
        self.phase: np.ndarray | None = None
        self._order_direction: int | None = None
        self._order: tuple[float, float] = (0.0, 0.0)
        self._buffers: dict[str, np.ndarray] = {}
        self.beam_offset: float | None = None
        self.clean_rings: bool | None = None
        self._concentration = 1.0
        self._cut: float | None = None
        self._ring_order: np.ndarray | None = None  # ring order (rows) of the first sweep with distinct rows
        self._sensor: tuple[tuple, SpinningSensor] | None = None
        self.frames = 0
        self.warnings_total = 0
        #: points' frame -> spin frame (the smallest rotation taking the spin axis to z), None while
        #: the two are the same
        self.rotation: np.ndarray | None = None
        self.spin_tilt_deg = 0.0
        self._find_axis = bool(find_spin_axis) and altitude is None
        warm_up()

    def _work(self, name: str, n: int, dtype) -> np.ndarray:
        """A work array of ``n`` entries kept from sweep to sweep (fresh megabyte arrays cost
        page faults on every sweep, about as much as the organising itself)."""
        buf = self._buffers.get(name)
        if buf is None or len(buf) < n or buf.dtype != dtype:
            buf = np.empty(max(n, int(1.25 * n)), dtype)
            self._buffers[name] = buf
        return buf[:n]

    # ------------------------------------------------------------------ public API
    def scan(
        self,
        xyz: np.ndarray,
        ring: np.ndarray | None = None,
        times: np.ndarray | None = None,
        intensity: np.ndarray | None = None,
        name: str = "000000",
        source: str = "<memory>",
        frame_time: float | None = None,
        gt_point_labels: np.ndarray | None = None,
        gt_point_instance: np.ndarray | None = None,
        gt_pose: np.ndarray | None = None,
    ) -> Scan:
        """Organise one sweep of points (input order) into a Scan with an exact slot map; its
        ``meta["organize_seconds"]`` is the time this took (PRC's cost on unorganised input)."""
        t_start = time.perf_counter()
        xyz = np.asarray(xyz)
        if xyz.ndim != 2 or xyz.shape[1] < 3:
            raise DataError(f"{source}: points must be an (N, 3) array, got shape {xyz.shape}")
        if xyz.dtype.kind not in "fiu":
            raise DataError(f"{source}: points of type {xyz.dtype} are not numeric")
        xyz = xyz[:, :3]
        n = len(xyz)
        for nm, arr in (
            ("ring", ring),
            ("times", times),
            ("intensity", intensity),
            ("gt_point_labels", gt_point_labels),
            ("gt_point_instance", gt_point_instance),
        ):
            if arr is not None and np.shape(arr) != (n,):
                raise DataError(f"{source}: {nm} has shape {np.shape(arr)} for {n} points")
        warnings: list[str] = []
        if ring is not None and self.method == "auto" and n > 1000 and (np.asarray(ring) == ring[0]).all():
            warnings.append(f"{source}: the ring field holds one value ({ring[0]}) for every point; ignored")
            ring = None
        cloud = np.empty((n, 3), np.float32)  # Scan.cloud, filled by _polar (no-return rows zeroed)
        if self._find_axis:
            self._find_axis = not self._spin_axis(xyz, source, warnings)
        if self.beam_offset is None:
            self.beam_offset = 0.0 if ring is not None else estimate_beam_offset(xyz, rotation=self.rotation)
        ok, rng, az, te = (
            self._work("ok", n, np.bool_),
            self._work("rng", n, np.float32),
            self._work("az", n, np.float32),
            self._work("te", n, np.float32),
        )
        if self.rotation is None:
            self._order = _polar(xyz, self.beam_offset, ok, rng, az, te, cloud)
        else:  # azimuths and elevations in the spin frame; Scan.cloud keeps the points as given
            spun = np.asarray(xyz, np.float64) @ self.rotation.T
            self._order = _polar(spun, self.beam_offset, ok, rng, az, te, cloud)
            cloud[ok] = xyz[ok]
        n_ok = int(ok.sum())
        if n_ok == 0:
            what = f"no point with a return ({n} points, all NaN/inf, at the origin or beyond 100 km)"
            if self._sensor is None:  # the first sweep: no geometry to give it
                raise DataError(f"{source}: {what}")
            return self._empty(cloud, name, source, frame_time, gt_point_labels, gt_point_instance, gt_pose, what)
        if times is not None:
            times = np.asarray(times, dtype=np.float64)
            if not np.isfinite(times[ok]).all():
                raise DataError(f"{source}: non-finite per-point times")
        if n_ok < n:
            warnings.append(
                f"{source}: {n - n_ok} of {n} points have no return (NaN/inf, at the origin or beyond 100 km); label 0"
            )

        method, row, rows = self._rows(xyz, ok, rng, az, te, ring, times, source, warnings)
        s, a0 = self._direction(az, ok, row, times, method, source)
        cols = self._columns(az, ok, row, rows, times, source)
        inv_step = cols / TWO_PI
        if self.phase is None or len(self.phase) != rows:
            self.phase = self._row_phases(az, row, rows, a0, s, inv_step)
        rep = self._work("rep", rows * cols, np.int64)
        slot, rep, per_row, collisions, multi = _scatter(az, rng, row, a0, s, inv_step, self.phase, rows, cols, rep)
        report = self._check(method, rows, cols, per_row, collisions, n_ok, n - n_ok, source, warnings, multi)
        scan = self._build(
            cloud, ok, rng, te, slot, rep, rows, cols, s, a0, times, intensity, name, source, frame_time,
            gt_point_labels, gt_point_instance, gt_pose, report, collisions,
        )  # fmt: skip
        t_end = time.perf_counter()
        scan.meta["organize_seconds"] = t_end - t_start
        scan.meta["organize_span"] = (t_start, t_end)  # perf_counter interval (overlap credit, pipeline.NextFrame)
        return scan

    def _spin_axis(self, xyz: np.ndarray, source: str, warnings: list[str]) -> bool:
        """Set :attr:`rotation` from the first sweep with 1,000 finite points when its spin axis is
        clearly off ``z`` (:data:`SPIN_AXIS_MIN_TILT_DEG`, :data:`SPIN_AXIS_MIN_GAIN`), and say so;
        whether the sweep decided it (False: too few points, the next sweep decides)."""
        if int(np.isfinite(xyz).all(axis=1).sum()) < 1000:
            return False
        axis, tilt, gain = estimate_spin_axis(xyz)
        if np.isnan(tilt):
            warnings.append(
                f"{source}: the beams bunch best about an axis {SPIN_AXIS_MAX_TILT_DEG:.0f} deg or more from the "
                "points' z axis (a sensor mounted on its side?): organised about z, which may fail; give the points "
                "in the sensor's frame"
            )
            return True
        if tilt < SPIN_AXIS_MIN_TILT_DEG or gain < SPIN_AXIS_MIN_GAIN:
            return True
        self.rotation = levelling_rotation(axis)
        self.spin_tilt_deg = tilt
        ax, ay, az_ = axis
        warnings.append(
            f"{source}: the sensor spun about ({ax:.3f}, {ay:.3f}, {az_:.3f}), {tilt:.1f} deg from the points' z axis "
            "(points in a vehicle or tilted frame?): organised about the spin axis (the points are not moved)"
        )
        return True

    def scan_organized(
        self,
        grid_xyz: np.ndarray,
        times: np.ndarray | None = None,
        intensity: np.ndarray | None = None,
        name: str = "000000",
        source: str = "<memory>",
        frame_time: float | None = None,
    ) -> Scan:
        """A sweep already organised as ``(H, W, 3)`` (rows = beams, e.g. the Ouster ROS driver).

        Zeros or NaN are no returns. Rows are put top beam first (by their median elevation);
        the slot map is the identity up to that row order; the sensor model (beam elevations,
        azimuth direction, per-row azimuth offsets) is estimated from the grid.
        """
        g = np.asarray(grid_xyz)
        if g.ndim != 3 or g.shape[2] < 3 or g.shape[0] < 1 or g.shape[1] < 2:
            raise DataError(f"{source}: an organised cloud must be (H, W, 3), got shape {g.shape}")
        H, W = g.shape[:2]
        src = g[..., :3].reshape(-1, 3)
        n_all = len(src)
        ok, rng, az, te = (np.empty(n_all, bool), np.empty(n_all, np.float32), np.empty(n_all), np.empty(n_all))
        flat = np.empty((n_all, 3), np.float32)
        _polar(src, 0.0, ok, rng, az, te, flat)
        if not ok.any():
            raise DataError(f"{source}: no point with a return in the {H} x {W} organised cloud")
        warnings: list[str] = []
        okg = ok.reshape(H, W)
        teg = np.where(okg, te.reshape(H, W), np.nan)
        with np.errstate(all="ignore"):
            med = np.array([np.nanmedian(r) if np.isfinite(r).any() else np.nan for r in teg])
        known = np.isfinite(med)
        empty_rows = int((~known).sum())
        if known.sum() >= 2:
            med = np.interp(np.arange(H), np.flatnonzero(known), med[known])
        else:
            med = np.where(known, med, med[known][0] if known.any() else 0.0)
        # rows without a return between rows with returns (every other beam off: a sensor in a
        # reduced-beam mode, a dead laser) go after the others, so that neighbouring beams are
        # neighbouring rows (interleaved, they left PRC no row neighbours: every return noise)
        have = np.flatnonzero(known)
        inner = ~known & (np.arange(H) > have[0]) & (np.arange(H) < have[-1]) if len(have) else np.zeros(H, bool)
        order = np.lexsort((-med, inner))  # top beam first (stable), the inner empty rows last
        inv = np.empty(H, np.int64)
        inv[order] = np.arange(H)
        if inner.any():
            warnings.append(
                f"{source}: {int(inner.sum())} of {H} rows of the organised cloud hold no return between rows that do "
                "(a reduced-beam mode?): put after the others, so that neighbouring beams are neighbouring rows"
            )
        ranked = order[~inner[order]]
        if not np.all(np.diff(ranked) > 0) and not np.all(np.diff(ranked) < 0):
            msg = f"{source}: rows of the organised cloud are not ordered by elevation; reordered top beam first"
            warnings.append(msg)
        row = np.repeat(inv, W)
        row[~ok] = -1
        # azimuth direction along the columns
        dg = np.where(okg[:, 1:] & okg[:, :-1], np.angle(np.exp(1j * np.diff(az.reshape(H, W), axis=1))), np.nan)
        s = 1 if np.nansum(np.sign(dg)) >= 0 else -1
        cols = W
        col = np.tile(np.arange(W), H)
        c_az = s * TWO_PI * (col + 0.5) / W
        a0 = float(np.angle(np.exp(1j * (az[ok] - c_az[ok])).mean()))
        offs = np.zeros(H)
        resid = np.where(ok, np.angle(np.exp(1j * (az - c_az - a0))), np.nan).reshape(H, W)
        offs_raw = _nanmedian_rows(resid)
        offs[inv] = np.nan_to_num(offs_raw)
        slot = np.repeat(inv, W) * W + col  # no-return points keep their own (empty) slot
        rep = np.full(H * W, -1, np.int64)
        rep[slot[ok]] = np.flatnonzero(ok)
        per_row = np.bincount(row[ok], minlength=H)
        self.expected_rows = self.expected_rows or H
        report = self._check("organized", H, W, per_row, 0, int(ok.sum()), int((~ok).sum()), source, warnings)
        report.empty_rows = max(report.empty_rows, empty_rows)
        sensor = SpinningSensor.create(
            np.arctan(med[order]), W, beam_azimuth=offs, azimuth0=a0, direction=s, sweep_period=self.sweep_period
        )
        t = None
        if times is not None:
            t = np.asarray(times, dtype=np.float64)
            if t.shape == (H, W):
                t = t[order]
            elif t.shape != (W,):
                raise DataError(f"{source}: times of shape {t.shape} for a {H} x {W} cloud")
        inten = None
        if intensity is not None:
            inten = np.asarray(intensity, dtype=np.float32)
            if inten.shape != (H, W):
                raise DataError(f"{source}: intensity of shape {inten.shape} for a {H} x {W} cloud")
            inten = inten[order]
        return self._finish(
            flat, ok, rng, slot, rep, H, cols, sensor, t, inten, name, source, frame_time, None, None, None, report, 0,
            slot_times_given=t is not None,
        )  # fmt: skip

    # ------------------------------------------------------------------ rows
    def _rows(self, xyz, ok, rng, az, te, ring, times, source, warnings):
        method = self.method
        if ring is not None and method in ("auto", "ring"):
            row, rows = self._rows_from_field(np.asarray(ring), ok, te, source, warnings)
            return "ring-field", row, rows
        if method == "ring":
            raise DataError(f"{source}: organiser method 'ring' but the source has no ring field")
        layout = "unordered"
        if method in ("auto", "order"):
            # steps under 45 deg: beams with azimuth offsets (Ouster OS-0: +-11 deg) make
            # column-major steps large
            frac, total = self._order
            revs = abs(total) / TWO_PI
            if frac > 0.7 and revs >= 1.5:
                layout = "ring-major"
            elif frac > 0.7:
                layout = "column-major"
            elif method == "order":
                raise DataError(
                    f"{source}: the point order is not consistent (only {100 * frac:.0f}% of consecutive points "
                    "are neighbours in azimuth); use method 'beams' or 'auto'"
                )
            self._order_direction = 1 if total >= 0 else -1
        if layout == "ring-major":
            row, rows = self._rows_ring_major(ok, rng, az, te, source, warnings)
            return "ring-major", row, rows
        row, rows = self._rows_from_beams(ok, rng, te, source, warnings)
        return ("column-major" if layout == "column-major" else "beams"), row, rows

    def _rows_from_field(self, ring, ok, te, source, warnings):
        if not np.issubdtype(ring.dtype, np.integer):
            if not np.isfinite(ring[ok]).all() or (ring[ok] != np.round(ring[ok])).any():
                raise DataError(f"{source}: the ring field holds non-integer values")
            ring = ring.astype(np.int64)
        ids, inv = np.unique(ring[ok], return_inverse=True)
        if self.ring_ids is not None and not np.isin(ids, self.ring_ids).all():
            new = ~np.isin(ids, self.ring_ids)
            warnings.append(f"{source}: ring ids {ids[new].tolist()[:8]} not seen before; beam table rebuilt")
            self.ring_ids = None
        if self.ring_ids is None:
            self._ring_table(ids, inv, ok, te)
            return self._ring_rows(ring, ok), len(self.ring_ids)
        row = self._ring_rows(ring, ok)
        if not self._rings_at_their_elevations(row, ok, te):
            warnings.append(
                f"{source}: the ring ids are no longer at the elevations of the first sweep's (renumbered?); "
                "beam table rebuilt from this sweep"
            )
            self._ring_table(ids, inv, ok, te)
            row = self._ring_rows(ring, ok)
        return row, len(self.ring_ids)

    def _ring_table(self, ids, inv, ok, te) -> None:
        """Ring ids in row order (top beam first) and the beam table, from the rings' median elevations."""
        med = np.array([np.median(te[ok][inv == k]) for k in range(len(ids))])  # once per sequence
        self.ring_ids = ids[np.argsort(-med, kind="stable")]
        self.beam_te = np.sort(med)[::-1]
        if self.expected_rows is None:
            self.expected_rows = len(ids)

    def _ring_rows(self, ring, ok) -> np.ndarray:
        """Row of every point from its ring id (-1 for no-return points)."""
        order = np.argsort(self.ring_ids)
        row = np.full(len(ok), -1, np.int64)
        row[ok] = order[np.searchsorted(self.ring_ids[order], ring[ok])]
        return row

    def _rings_at_their_elevations(self, row, ok, te, every: int = 16) -> bool:
        """Whether the rings of a sweep (rows from the ring field) still lie at their rows' beam
        elevations: the median elevation of every ``every``-th return per row within half the
        gap to the neighbouring beams, for at least three quarters of the rows with 8 samples or
        more (a ring field renumbered between sweeps would silently scramble the rows)."""
        rows = len(self.beam_te)
        if rows < 2:
            return True
        idx = np.flatnonzero(ok)[::every]
        r, t = row[idx], te[idx]
        sort = np.lexsort((t, r))
        cnt = np.bincount(r, minlength=rows)
        start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
        used = cnt >= 8
        if not used.any():
            return True
        med = np.arctan(t[sort][start[used] + cnt[used] // 2])
        beams = np.arctan(self.beam_te)
        gap = np.abs(np.diff(beams))
        half = 0.5 * np.minimum(np.append(gap, np.inf), np.append(np.inf, gap))
        off = np.abs(med - beams[used]) > half[used]
        return off.sum() <= 0.25 * used.sum()

    def _rows_ring_major(self, ok, rng, az, te, source, warnings):
        s = self._order_direction
        if self.cols:
            step_guess = TWO_PI / self.cols
        else:  # the typical azimuth step between consecutive points of a ring
            idx = np.flatnonzero(ok)[:50000]
            d = np.abs(np.angle(np.exp(1j * np.diff(az[idx]))))
            d = d[(d > 1e-7) & (d < np.radians(5.0))]
            step_guess = float(np.median(d)) if len(d) > 10 else np.radians(0.1)
        if self._cut is None:
            # first sweep: cut where the azimuth comes back to the ring's start, to find the
            # sweep's cut azimuth
            run = _ring_runs(az, ok, float(s), np.radians(15.0), 0.5 * step_guess)
            lo, hi = _run_bounds(run, int(run.max()) + 1)
            self._cut = self._cut_azimuth(az, lo, hi, s, step_guess)
        # cut the rings where they pass the sweep's cut azimuth (late ring starts do not chain)
        run = self._work("run", len(az), np.int64)
        n_runs = _ring_runs_cut(az, ok, float(s), self._cut, np.radians(15.0), run)
        lo, hi = _run_bounds(run, n_runs)
        self._cut = self._cut_azimuth(az, lo, hi, s, step_guess)  # followed from sweep to sweep
        med, cnt = _run_medians(te, ok, lo, hi)
        if self.beam_te is None:
            self.beam_te = self._beams_from_runs(med, cnt)
        bounds = _beam_bounds(self.beam_te)
        row_of_run = _nearest_beam(med, cnt > 0, bounds, np.empty(len(med), np.int64))
        row_of_run = self._follow_ring_order(med, cnt, row_of_run, source, warnings)
        if self.clean_rings is None:
            # rings are elevation-clean when points of one ring spread far less than the beam gap
            spread = _run_spread(te, ok, lo, hi, med)
            gaps = np.abs(np.diff(np.arctan(self.beam_te))) if len(self.beam_te) > 1 else np.array([1.0])
            sp = float(np.nanmedian(np.arctan(spread[cnt >= 0.2 * cnt.max()]))) if (cnt > 0).any() else 0.0
            self.clean_rings = bool(sp < 0.1 * float(np.median(gaps)))
        window = int(max(32, 0.1 * float(np.median(cnt[cnt > 0]))))
        row = self._work("row", len(te), np.int64)
        _refine_cuts(te, ok, run, lo, hi, row_of_run, self.beam_te, window, self.clean_rings, row)
        return row, len(self.beam_te)

    def _follow_ring_order(self, med, cnt, nearest, source, warnings):
        """Rows of the runs of a ring-major sweep, following the ring order of the first sweep.

        A ring's median elevation moves with the azimuths where it has returns (a motion-
        compensated sweep, e.g. KITTI's, bends each ring's elevation by up to a beam gap along
        the azimuth), so the nearest beam by median alone sends rings to a neighbour's row (KITTI 00
        frames 7-15: 5-7 rows doubled, 12-19 % of the points sharing a slot). The driver writes
        the rings in the same order in every sweep: the first sweep whose rings take distinct
        nearest-beam rows sets that order, and the runs of every later sweep are aligned to
        it (:func:`_align_runs`). When they do not fit that order (over a beam gap off on average),
        a warning, and the nearest beams."""
        have = cnt > 0
        if self._ring_order is None:
            seq = nearest[have]
            if len(seq) >= 2 and len(np.unique(seq)) == len(seq):  # else: the next sweep may set it
                self._ring_order = seq.copy()
            return nearest
        seq = self._ring_order
        if not have.any():
            return nearest
        beam_ang = np.arctan(self.beam_te)
        gap = float(np.median(np.abs(np.diff(beam_ang))))
        entry, cost = _align_runs(np.arctan(med[have]), beam_ang[seq], max(gap, 1e-9), RING_REUSE_COST)
        if cost > 1.0:
            warnings.append(
                f"{source}: the rings do not follow the first sweep's ring order (off by {cost:.1f} beam gaps "
                "on average); rows from the nearest beam elevations"
            )
            return nearest
        out = nearest.copy()
        out[have] = seq[entry]
        return out

    @staticmethod
    def _row_phases(az, row, rows, a0, s, inv_step):
        """Every row's column phase (where its returns sit within a column, in columns),
        unwrapped to within half a column of the sweep's common phase, so that the rows'
        columns line up: a row at phase 0.999 and one at 0.001 are the same columns, not one
        apart. Rows without a clear phase (firings drifting through the column) take the
        common phase."""
        phase, strength = _row_phase(az, row, rows, a0, s, inv_step)
        w = strength * np.bincount(row[row >= 0], minlength=rows)[:rows]
        if w.sum() > 0:
            ref = float(np.angle(np.sum(w * np.exp(2j * np.pi * phase))) / (2.0 * np.pi))
        else:
            ref = 0.5
        ref = ref - np.floor(ref)
        rel = phase - ref
        rel = rel - np.round(rel)  # [-0.5, 0.5] around the common phase
        return np.where(strength > 0.3, ref + rel, ref)

    @staticmethod
    def _cut_azimuth(az, lo, hi, s, step):
        """The sweep's cut azimuth: early among the ring starts (late starts are rings whose
        first returns are missing), half a step before it."""
        cnt = hi - lo
        long = (lo >= 0) & (cnt >= 0.2 * cnt.max())
        starts = az[lo[long]]
        ref = float(np.angle(np.exp(1j * starts).mean()))
        rel = s * np.angle(np.exp(1j * (starts - ref)))
        return ref + s * float(np.percentile(rel, 2)) - s * 0.5 * step

    def _beams_from_runs(self, med, cnt):
        """Beam table from the rings of a ring-major sweep: run medians, runs of one beam merged."""
        good = cnt >= max(8, 0.01 * cnt.max())
        m = np.sort(med[good])[::-1]
        if len(m) == 0:
            m = np.sort(med[cnt > 0])[::-1]
        ang = np.arctan(m)
        gaps = -np.diff(ang)
        tol = 0.25 * float(np.median(gaps[gaps > np.radians(0.02)])) if (gaps > np.radians(0.02)).any() else 0.0
        groups = np.concatenate([[0], np.cumsum(gaps > max(tol, np.radians(0.02)))])
        beams = np.array([np.mean(ang[groups == g]) for g in range(groups[-1] + 1)])
        if self.expected_rows is not None and len(beams) != self.expected_rows:
            pass  # reported by the plausibility check
        return np.tan(beams)

    def _rows_from_beams(self, ok, rng, te, source, warnings):
        if self.beam_te is None:
            beam_te, conc = estimate_beams(te[ok], rng[ok], self.expected_rows)
            if len(beam_te) == 0:
                raise DataError(f"{source}: cannot organise: no beam structure in the elevations")
            if conc < MIN_BEAM_CONCENTRATION and len(beam_te) > 1:
                raise DataError(
                    f"{source}: cannot organise: the point elevations show no beam structure "
                    f"(only {100 * conc:.0f}% of points near one of {len(beam_te)} elevation peaks) and the "
                    "points carry no ring field and no consistent order"
                )
            self.beam_te = beam_te
            self._concentration = conc
        else:
            # does this sweep still fit the sequence's beam table? (checked on a sample)
            sub = slice(None, None, max(1, len(te) // 5000))  # a share: 5,000 points tell it to ~1 %
            conc = beam_concentration(te[sub][ok[sub]], self.beam_te)
            if conc < min(MIN_BEAM_CONCENTRATION, self._concentration - 0.15):
                warnings.append(
                    f"{source}: only {100 * conc:.0f}% of the points lie near the beams found on the first sweep "
                    f"({100 * self._concentration:.0f}% there): the beam table does not fit this sweep"
                )
        row = _nearest_beam(te, ok, _beam_bounds(self.beam_te), self._work("row", len(te), np.int64))
        return row, len(self.beam_te)

    # ------------------------------------------------------------------ columns
    def _direction(self, az, ok, row, times, method, source):
        if self.direction is None:
            s = 1
            if times is not None:
                # the azimuth's direction of travel in time, from time-sorted points of each row
                idx = np.flatnonzero(ok)
                sub = idx[np.argsort(times[idx], kind="stable")]
                d = np.angle(np.exp(1j * np.diff(az[sub])))
                same = row[sub][1:] == row[sub][:-1]
                d = d[same & (np.abs(d) < np.radians(10.0))]
                s = 1 if d.sum() >= 0 else -1
            elif self._order_direction is not None and method in ("ring-major", "column-major"):
                s = self._order_direction  # the input order is the firing order
            self.direction = s
        if self.a0 is None:
            first = int(np.argmax(ok))
            if times is not None:
                idx = np.flatnonzero(ok)
                first = int(idx[np.argmin(times[idx])])
            self.a0 = float(az[first])
        return self.direction, self.a0

    def _columns(self, az, ok, row, rows, times, source):
        if self.cols is not None:
            return self.cols
        steps = _row_steps(az, row, rows, np.radians(5.0))
        ordered = len(steps) > 0.5 * ok.sum()
        if not ordered:
            # unordered input: sort the azimuths of the most populated rows
            counts = np.bincount(row[row >= 0], minlength=rows)
            parts = []
            for r in np.argsort(counts)[::-1][: min(8, rows)]:
                a = np.sort(az[row == r])
                d = np.diff(a)
                parts.append(d[(d > 1e-7) & (d < np.radians(5.0))])
            steps = np.concatenate(parts) if parts else steps
        if len(steps) < 10:
            raise DataError(f"{source}: cannot estimate the column count (too few points along the rings)")
        # the firing step: steps over missing returns are whole multiples of it, so keep the
        # steps near the lower quartile (a sparse ring's median would skip firings)
        q = float(np.percentile(steps, 25))
        step = float(np.median(steps[steps < 1.5 * q]))
        cols = round(TWO_PI / step) if step > 0 else MAX_COLUMNS + 1
        if cols > MAX_COLUMNS:
            raise DataError(
                f"{source}: cannot organise: the azimuth steps along the rings ({np.degrees(step):.4f} deg) would give "
                f"{cols} columns per turn, more than any spinning sensor ({MAX_COLUMNS}): not a sweep seen from its "
                "sensor (a map tile, a cloud in a world frame?); give --cols if it is one"
            )
        self.cols = max(1, cols)
        return self.cols

    # ------------------------------------------------------------------ checks and the Scan
    def _check(self, method, rows, cols, per_row, collisions, n_ok, n_bad, source, warnings, multi=0) -> OrganizeReport:
        found = int((per_row > 0).sum())
        empty = int(rows - found)
        # further returns of one firing share their slot by nature: only the others count
        coll = (collisions - multi) / max(n_ok, 1)
        expected = self.expected_rows
        if n_ok > 4 * cols and coll > MAX_COLLISIONS:
            raise DataError(
                f"{source}: cannot organise: {100 * coll:.0f}% of the points share a range-image slot "
                f"({found} rings found, {cols} columns, method {method})"
            )
        if found == 1 and n_ok > 4 * cols:
            raise DataError(f"{source}: cannot organise: all {n_ok} points fell in one ring ({method})")
        if coll > WARN_COLLISIONS:
            warnings.append(
                f"{source}: {100 * coll:.1f}% of the points share a range-image slot with a point of another "
                f"firing (method {method}, {found} rings, {cols} columns)"
            )
        if expected is not None and found < 0.75 * expected:
            warnings.append(f"{source}: {found} rings found, the sensor has {expected}")
        if expected is not None and rows != expected and found >= 0.75 * expected:
            warnings.append(f"{source}: {rows} beams found, the sensor has {expected}")
        if n_ok > 1000 and n_ok < MIN_OCCUPANCY * rows * cols:
            warnings.append(
                f"{source}: only {100 * n_ok / (rows * cols):.1f}% of the {rows} x {cols} range image's slots hold a "
                f"point (method {method}): the rings or the column count are likely wrong"
            )
        if rows and empty > 0.25 * rows:
            warnings.append(f"{source}: {empty} of {rows} rows hold no point")
        for w in warnings:
            log.warning(w)
        self.warnings_total += len(warnings)
        self.frames += 1
        return OrganizeReport(
            method, found, expected, cols, 100.0 * collisions / max(n_ok, 1), empty, n_bad, warnings, int(multi)
        )

    def _build(
        self, xyz, ok, rng, te, slot, rep, rows, cols, s, a0, times, intensity, name, source, frame_time,
        gt_point_labels, gt_point_instance, gt_pose, report, collisions,
    ):  # fmt: skip
        sensor = self._sensor_model(rows, cols, s, a0)
        inten = None
        if intensity is not None:
            src = np.asarray(intensity)
            if src.dtype.kind not in "fiub":
                raise DataError(f"{source}: intensity of type {src.dtype} is not numeric")
            inten = _gather(rep, src, np.empty(rows * cols, np.float32)).reshape(rows, cols)
        t = None
        if times is not None:
            t = self._slot_times(times, rep, rows, cols)
        scan = self._finish(
            xyz, ok, rng, slot, rep, rows, cols, sensor, t, inten, name, source, frame_time,
            gt_point_labels, gt_point_instance, gt_pose, report, collisions, slot_times_given=times is not None,
        )  # fmt: skip
        return scan

    def _empty(self, cloud, name, source, frame_time, gt_point_labels, gt_point_instance, gt_pose, what) -> Scan:
        """A sweep without a single return after sweeps that had some (an empty message, a blocked
        sensor): the sequence's range image with every slot empty, each input point (if any) in an
        empty slot with label 0, said once per sweep, so that the frame keeps its place in every
        output (label files, rewritten recordings) instead of being skipped."""
        sensor = self._sensor[1]
        rows, cols = sensor.rows, sensor.cols
        n = len(cloud)
        warnings = [f"{source}: {what}: an empty sweep, every point labelled no return"] if n else []
        for w in warnings:  # (a sweep of no points at all is said by the pipeline)
            log.warning(w)
        self.warnings_total += len(warnings)
        self.frames += 1
        report = OrganizeReport("empty", 0, self.expected_rows, cols, 0.0, rows, n, warnings)
        none, empty = np.zeros(n, np.int64), np.full(rows * cols, -1, np.int64)  # every point in slot 0, empty
        return self._finish(
            cloud, np.zeros(n, bool), np.zeros(n, np.float32), none, empty, rows, cols, sensor, None, None, name,
            source, frame_time, gt_point_labels, gt_point_instance, gt_pose, report, 0, slot_times_given=False,
        )  # fmt: skip

    def _sensor_model(self, rows: int, cols: int, s: int, a0: float) -> SpinningSensor:
        """The sequence's sensor model, one object for as long as its parameters hold (its
        slot directions are then computed once per sequence, not once per sweep)."""
        altitude = np.arctan(self.beam_te) if self.beam_te is not None and len(self.beam_te) == rows else np.zeros(rows)
        beam_azimuth = s * (TWO_PI / cols) * (self.phase - 0.5)
        key = (rows, cols, s, a0, self.sweep_period, altitude.tobytes(), beam_azimuth.tobytes())
        if self._sensor is None or self._sensor[0] != key:
            sensor = SpinningSensor.create(
                altitude, cols, beam_azimuth=beam_azimuth, azimuth0=a0, direction=s, sweep_period=self.sweep_period,
                mount=None if self.rotation is None else self.rotation.T,
            )  # fmt: skip
            self._sensor = (key, sensor)
        return self._sensor[1]

    def _slot_times(self, times, rep, rows, cols):
        """Per-slot times: the representative's; empty slots take their column's mean time
        (columns without any point interpolated, cyclically)."""
        t, col_t, known = _slot_times_kernel(np.ascontiguousarray(times, dtype=np.float64), rep, rows, cols)
        if not known.all():
            if not known.any():
                col_t[:] = 0.0
            else:
                k = np.flatnonzero(known)
                col_t = np.interp(np.arange(cols), k, col_t[k])
            t = _fill_empty_times(t, rep, col_t, rows, cols)
        return t.reshape(rows, cols)

    def _finish(
        self, cloud, ok, rng, slot, rep, rows, cols, sensor, t, inten, name, source, frame_time,
        gt_point_labels, gt_point_instance, gt_pose, report, collisions, slot_times_given,
    ):  # fmt: skip
        size = rows * cols
        ranges, slot_xyz = _fill_slots(rep, rng, cloud)
        point_slot = slot
        if report.nonfinite_points:
            lost = slot < 0
            if lost.any():
                empty = np.flatnonzero(rep < 0)
                if len(empty) == 0:
                    raise DataError(
                        f"{source}: {int(lost.sum())} no-return points but the range image has no empty slot "
                        "to hold them"
                    )
                point_slot = slot.copy()
                point_slot[lost] = empty[0]
        if frame_time is None:
            frame_time = float(np.min(t)) if t is not None else self.frames * self.sweep_period
        if t is None and not slot_times_given and self.spin is not None:
            # the source fixes its time convention: column c fired at (c + 0.5) / cols of the
            # sweep (columns follow time). Without it no times are made up (no deskewing).
            t = frame_time + (np.arange(cols) + 0.5) / cols * self.sweep_period
        gt_slot = gt_inst = None
        if gt_point_labels is not None:
            src = np.ascontiguousarray(gt_point_labels, dtype=np.uint8)
            gt_slot = _gather(rep, src, np.empty(size, np.uint8)).reshape(rows, cols)
        if gt_point_instance is not None:
            src = np.ascontiguousarray(gt_point_instance, dtype=np.uint32)
            gt_inst = _gather(rep, src, np.empty(size, np.uint32)).reshape(rows, cols)
        return Scan(
            ranges=ranges.reshape(rows, cols),
            sensor=sensor,
            name=name,
            source=source,
            intensity=inten,
            timestamps=t,
            xyz=slot_xyz.reshape(rows, cols, 3),
            cloud=cloud,
            point_slot=point_slot,
            gt_labels=gt_slot,
            gt_point_labels=None if gt_point_labels is None else np.asarray(gt_point_labels),
            gt_instance=gt_inst,
            gt_pose=gt_pose,
            meta={"organize": report.as_dict(), "collisions": int(collisions), "frame_time": float(frame_time)},
        )
