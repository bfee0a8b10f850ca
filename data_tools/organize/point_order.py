"""Rows from the point order, when it is consistent.

*Ring-major* (one beam's sweep after the other, detected as several azimuth revolutions along the
order, either direction) is cut into rings where the azimuth restarts a revolution, the cut refined
point by point by elevation; each ring is then matched to a beam by its median elevation, so
missing or split rings do not shift the rows, and to the ring order of the sequence's first sweep
(:class:`RingMajor`). *Column-major* (all beams of one firing, then the next: one revolution along
the order) takes its rows from the beam elevations (:func:`~data_tools.organize.beams.rows_from_beams`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit

from data_tools.errors import DataError
from data_tools.organize.beams import beam_bounds, nearest_beam
from data_tools.organize.polar import TWO_PI, wrap_angles

#: cost (in beam gaps) of giving a run the row of the run before it in a ring-major sweep (a ring
#: cut in two), against one row further along the first sweep's ring order
RING_REUSE_COST = 0.5


def order_layout(frac: float, total: float, method: str, source: str) -> tuple[str, int]:
    """The layout of a sweep's point order (``ring-major``, ``column-major`` or ``unordered``) and
    its azimuth direction, from :func:`~data_tools.organize.polar.polar`'s figures: ``frac``, the
    share of azimuth steps under 45 deg between consecutive returns (beams with azimuth offsets,
    Ouster OS-0's +-11 deg, make column-major steps large), and ``total``, their signed sum.

    Raises
    ------
    DataError
        For ``method="order"`` when the order is not consistent."""
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
    else:
        layout = "unordered"
    return layout, 1 if total >= 0 else -1


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


class RingMajor:
    """Rows of ring-major sweeps, with what the sequence's first sweeps fixed: the cut azimuth
    (followed from sweep to sweep), the ring order and whether rings are elevation-clean."""

    def __init__(self) -> None:
        self.cut: float | None = None
        self.ring_order: np.ndarray | None = None  # ring order (rows) of the first sweep with distinct rows
        self.clean_rings: bool | None = None

    def rows(
        self,
        ok: np.ndarray,
        az: np.ndarray,
        te: np.ndarray,
        s: int,
        cols: int | None,
        beam_te: np.ndarray | None,
        work: Callable[[str, int, type], np.ndarray],
        source: str,
        warnings: list[str],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Row of every point (-1 for no-return points) of a ring-major sweep turning in direction
        ``s``, and the beam table (``beam_te``, or from this sweep's rings when None). ``work``
        gives the work arrays kept from sweep to sweep."""
        if cols:
            step_guess = TWO_PI / cols
        else:  # the typical azimuth step between consecutive points of a ring
            idx = np.flatnonzero(ok)[:50000]
            d = np.abs(wrap_angles(np.diff(az[idx])))
            d = d[(d > 1e-7) & (d < np.radians(5.0))]
            step_guess = float(np.median(d)) if len(d) > 10 else np.radians(0.1)
        if self.cut is None:
            # first sweep: cut where the azimuth comes back to the ring's start, to find the
            # sweep's cut azimuth
            run = _ring_runs(az, ok, float(s), np.radians(15.0), 0.5 * step_guess)
            lo, hi = _run_bounds(run, int(run.max()) + 1)
            self.cut = cut_azimuth(az, lo, hi, s, step_guess)
        # cut the rings where they pass the sweep's cut azimuth (late ring starts do not chain)
        run = work("run", len(az), np.int64)
        n_runs = _ring_runs_cut(az, ok, float(s), self.cut, np.radians(15.0), run)
        lo, hi = _run_bounds(run, n_runs)
        self.cut = cut_azimuth(az, lo, hi, s, step_guess)  # followed from sweep to sweep
        med, cnt = _run_medians(te, ok, lo, hi)
        if beam_te is None:
            beam_te = beams_from_runs(med, cnt)
        row_of_run = nearest_beam(med, cnt > 0, beam_bounds(beam_te), np.empty(len(med), np.int64))
        row_of_run = self._follow_ring_order(med, cnt, row_of_run, beam_te, source, warnings)
        if self.clean_rings is None:
            # rings are elevation-clean when points of one ring spread far less than the beam gap
            spread = _run_spread(te, ok, lo, hi, med)
            gaps = np.abs(np.diff(np.arctan(beam_te))) if len(beam_te) > 1 else np.array([1.0])
            sp = float(np.nanmedian(np.arctan(spread[cnt >= 0.2 * cnt.max()]))) if (cnt > 0).any() else 0.0
            self.clean_rings = bool(sp < 0.1 * float(np.median(gaps)))
        window = int(max(32, 0.1 * float(np.median(cnt[cnt > 0]))))
        row = work("row", len(te), np.int64)
        _refine_cuts(te, ok, run, lo, hi, row_of_run, beam_te, window, self.clean_rings, row)
        return row, beam_te

    def _follow_ring_order(self, med, cnt, nearest, beam_te, source, warnings):
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
        if self.ring_order is None:
            seq = nearest[have]
            if len(seq) >= 2 and len(np.unique(seq)) == len(seq):  # else: the next sweep may set it
                self.ring_order = seq.copy()
            return nearest
        seq = self.ring_order
        if not have.any():
            return nearest
        beam_ang = np.arctan(beam_te)
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


def cut_azimuth(az: np.ndarray, lo: np.ndarray, hi: np.ndarray, s: int, step: float) -> float:
    """The sweep's cut azimuth: early among the ring starts (late starts are rings whose
    first returns are missing), half a step before it."""
    cnt = hi - lo
    long = (lo >= 0) & (cnt >= 0.2 * cnt.max())
    starts = az[lo[long]]
    ref = float(np.angle(np.exp(1j * starts).mean()))
    rel = s * wrap_angles(starts - ref)
    return ref + s * float(np.percentile(rel, 2)) - s * 0.5 * step


def beams_from_runs(med: np.ndarray, cnt: np.ndarray) -> np.ndarray:
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
    return np.tan(beams)
