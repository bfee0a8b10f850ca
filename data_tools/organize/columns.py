"""Columns and slots: each point's column from its azimuth, and the range image's slots.

Columns come from the azimuth: direction detected from the point order (or the per-point times),
bin width ``2*pi/cols`` with ``cols`` from the sensor when known, else estimated from the median
azimuth step between consecutive points of a ring (:func:`column_count`); every row's bin phase is
estimated too (beams with an azimuth offset, e.g. Ouster's, fall in the middle of their bins,
:func:`row_phases`). :func:`scatter` then puts every point in its slot, the nearest point of a
slot representing it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from data_tools.errors import DataError
from data_tools.organize.polar import TWO_PI, wrap_angles

#: columns per turn above which an estimate is refused (the finest spinning sensors: 0.05 deg, 7,200
#: a turn; a map tile's points, steps of micro-degrees seen from a corner, gave 360,391 and 16 s)
MAX_COLUMNS = 16384


@njit(cache=True, nogil=True)
def wrap(a):
    """One angle (rad) wrapped into (-pi, pi]."""
    while a > np.pi:
        a -= 2.0 * np.pi
    while a <= -np.pi:
        a += 2.0 * np.pi
    return a


def azimuth_direction(
    az: np.ndarray, ok: np.ndarray, row: np.ndarray, times: np.ndarray | None, order_direction: int | None
) -> int:
    """The direction the azimuth turns in time (1: increasing): from the time-sorted points of each
    row when there are per-point times, else ``order_direction`` (the point order's, when the
    input order is the firing order), else 1."""
    if times is not None:
        idx = np.flatnonzero(ok)
        sub = idx[np.argsort(times[idx], kind="stable")]
        d = wrap_angles(np.diff(az[sub]))
        same = row[sub][1:] == row[sub][:-1]
        d = d[same & (np.abs(d) < np.radians(10.0))]
        return 1 if d.sum() >= 0 else -1
    return 1 if order_direction is None else order_direction


def start_azimuth(az: np.ndarray, ok: np.ndarray, times: np.ndarray | None) -> float:
    """The azimuth where the sweep starts: of the first point in time (or in order)."""
    first = int(np.argmax(ok))
    if times is not None:
        idx = np.flatnonzero(ok)
        first = int(idx[np.argmin(times[idx])])
    return float(az[first])


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
            d = abs(wrap(az[i] - az[j]))
            if d > 1e-7 and d < max_step:
                out[c] = d
                c += 1
        last[r] = i
    return out[:c]


def column_count(az: np.ndarray, ok: np.ndarray, row: np.ndarray, rows: int, source: str) -> int:
    """Columns per turn, from the firing step along the rings (the points' order when it follows
    the rings, else the sorted azimuths of the most populated rows).

    Raises
    ------
    DataError
        When too few points lie along the rings, or the step gives more than :data:`MAX_COLUMNS`."""
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
    return max(1, cols)


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


def row_phases(az: np.ndarray, row: np.ndarray, rows: int, a0: float, s: int, inv_step: float) -> np.ndarray:
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


@njit(cache=True, nogil=True)
def scatter(az, rng, row, a0, s, inv_step, phase, rows, cols, rep):
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
            if abs(wrap(az[i] - az[j])) < same:
                multi += 1
            if rng[i] < rng[j]:
                rep[k] = i
    return slot, rep, per_row, collisions, multi


@njit(cache=True, nogil=True)
def gather(rep, src, out):
    """``out[k] = src[rep[k]]`` for occupied slots (``rep[k] >= 0``), 0 elsewhere."""
    for k in range(rep.shape[0]):
        j = rep[k]
        out[k] = src[j] if j >= 0 else 0
    return out


@njit(cache=True, nogil=True)
def fill_slots(rep, rng, xyz):
    """Range and coordinates of every slot's representative (zeros for empty slots)."""
    size = rep.shape[0]
    ranges = np.empty(size, np.float32)
    out = np.empty((size, 3), np.float32)
    for k in range(size):
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
    return ranges, out


@njit(cache=True, nogil=True)
def _representative_times(times, rep, rows, cols):
    """Time of every slot's representative (empty slots left unset), and the mean time of each
    column's points (0 for columns without points, which are flagged in ``known``)."""
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
    return t, col_t, known


@njit(cache=True, nogil=True)
def _fill_empty_times(t, rep, col_t, rows, cols):
    for k in range(rows * cols):
        if rep[k] < 0:
            t[k] = col_t[k % cols]
    return t


def slot_times(times: np.ndarray, rep: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Per-slot times: the representative's; empty slots take their column's mean time
    (columns without any point interpolated, cyclically)."""
    t, col_t, known = _representative_times(np.ascontiguousarray(times, dtype=np.float64), rep, rows, cols)
    if known.any() and not known.all():
        k = np.flatnonzero(known)
        col_t = np.interp(np.arange(cols), k, col_t[k])
    return _fill_empty_times(t, rep, col_t, rows, cols).reshape(rows, cols)
