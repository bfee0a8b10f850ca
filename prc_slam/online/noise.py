"""The range noise of a spinning sensor's sweep, and the baseline it asks of the coarse classifier.

The coarse classifier (paper 001, Sec. 4) calls a return vegetation when the signed angles ``sV``
of successive steps ``D_k = X_{k+1} - X_k`` up its scan line switch fast between its states
(-90, 0, 90 deg, each with a spread of ``veg_sigma`` = 20 deg). A step whose length is comparable
to the range noise has a direction set by the noise: up a car's face, returns lie ``range x beam
gap`` apart (an OS0-128's 0.71 deg: 3 cm at 2.6 m, under its 3 cm range noise), the signed angles
alternate and a car body beside the sensor becomes vegetation. A step of length ``s`` across
noise of ``sigma`` per coordinate (``sqrt(2) sigma`` on a difference) turns by up to
``atan(sqrt(2) sigma / s)``; it stays within the states' spread when
``s >= sqrt(2) sigma / tan(veg_sigma)`` (:func:`noise_baseline`): 0.117 m at 3 cm, 0.078 m at
2 cm, 0.044 m at KITTI's 1.1 cm. Returns whose column spacing is under that baseline lie in the
noise regime (:func:`noise_regime`); there :class:`~prc_slam.online.detector.OnlineDetector`
judges the classifier's vegetation calls again with its steps taken over the baseline
(``CoarseParams.min_step``) instead of to the next return (``noise_labels``; step 6 of
:mod:`prc_slam.online.spinning` does so where the noise turns the steps by its own
``vegetation_regime``, 30 deg).

Where a column does not resolve a surface at all (its returns farther apart than
``SpinningCarParams.veg_resolution``) the ring still may: :func:`ring_surface` tells a smooth surface
along the ring (``ring_labels``).

The noise is measured on the sweep itself (:func:`range_noise`), not read from a data sheet: along a
ring, three successive returns on one surface have ranges whose second difference is the noise
(``sqrt(6) sigma``) plus the surface's curvature in azimuth, which on a road ring (a circle around
the sensor) or a wall is far under it at the ring's spacing; a robust spread (the median absolute
value) ignores the edges and foliage. Simulated sweeps (range sigma 0.02 / 0.03 m): 0.020 on hdl64
and hdl32, 0.030-0.031 on vlp16 and the Ouster layouts; KITTI 00 frame 0: 0.011 m.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: m: a ring triple whose two steps in range both stay under this lies on one surface
MAX_RANGE_STEP = 0.5
#: least ring triples for an estimate (fewer: :func:`range_noise` gives NaN)
MIN_TRIPLES = 200
#: MAD to standard deviation of a normal distribution
MAD_TO_SIGMA = 1.4826
#: deg: halfway between two of the coarse classifier's states (90 deg apart): a ring turning less
#: than this is one surface (:func:`ring_surface`), a signed angle under it is nearer vertical
HALFWAY_DEG = 45.0


def range_noise(ranges: np.ndarray, max_step: float = MAX_RANGE_STEP, row_stride: int = 1) -> float:
    """The range noise (standard deviation, m) of a spinning sensor's sweep from its rings.

    Parameters
    ----------
    ranges : ndarray, shape (rows, cols)
        Range image (rows: beams, columns: azimuth in firing order); 0 or less: no return.
    max_step : float
        Triples whose range steps to either neighbour exceed this (an edge, a gap) are left out.
    row_stride : int
        Every ``row_stride``-th ring only (a cheaper estimate on dense sensors).

    Returns
    -------
    float
        ``MAD_TO_SIGMA x median |r[c-1] - 2 r[c] + r[c+1]| / sqrt(6)`` over the triples of one
        surface along every ring; NaN with fewer than :data:`MIN_TRIPLES` triples.
    """
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 2:
        raise ValueError(f"range_noise needs a (rows, cols) range image, got shape {r.shape}")
    if row_stride < 1:
        raise ValueError(f"row_stride must be >= 1, got {row_stride}")
    r = r[::row_stride]
    a, b, c = r[:, :-2], r[:, 1:-1], r[:, 2:]
    ok = (a > 0) & (b > 0) & (c > 0) & (np.abs(b - a) < max_step) & (np.abs(c - b) < max_step)
    if int(ok.sum()) < MIN_TRIPLES:
        return float("nan")
    d2 = np.abs(a - 2.0 * b + c)[ok]
    return float(MAD_TO_SIGMA * np.median(d2) / np.sqrt(6.0))


def noise_baseline(sigma: float, angle_sigma_deg: float) -> float:
    """The least step (m) whose direction the range noise ``sigma`` turns by no more than
    ``angle_sigma_deg`` (the coarse classifier's state spread): ``sqrt(2) sigma / tan(angle)``;
    0 for a non-finite or non-positive ``sigma`` (no baseline: the paper's successive steps)."""
    if not 0.0 < angle_sigma_deg < 90.0:
        raise ValueError(f"angle_sigma_deg must lie in (0, 90), got {angle_sigma_deg}")
    if not np.isfinite(sigma) or sigma <= 0.0:
        return 0.0
    return float(np.sqrt(2.0) * sigma / np.tan(np.radians(angle_sigma_deg)))


def beam_gaps(altitude: np.ndarray) -> np.ndarray:
    """Per row, the gap (rad) from its beam to the next beam up in elevation (the highest beam: the
    gap below it).

    Parameters
    ----------
    altitude : ndarray, shape (rows,)
        Beam elevations (rad), in the rows' order (any order).
    """
    alt = np.asarray(altitude, dtype=np.float64)
    if len(alt) < 2:
        return np.zeros(len(alt))
    order = np.argsort(alt, kind="stable")
    up = np.empty(len(alt))
    up[:-1] = np.diff(alt[order])
    up[-1] = up[-2]
    gap = np.empty(len(alt))
    gap[order] = np.abs(up)
    return gap


def column_spacing(ranges: np.ndarray, altitude: np.ndarray) -> np.ndarray:
    """Per slot, ``range x`` the gap (rad) to the next beam up in elevation (:func:`beam_gaps`):
    how far apart a column's returns lie up a surface facing the sensor.

    Parameters
    ----------
    ranges : ndarray, shape (rows, cols)
    altitude : ndarray, shape (rows,)
        Beam elevations (rad), in the rows' order (any order).
    """
    alt = np.asarray(altitude, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 2 or alt.shape != (r.shape[0],):
        raise ValueError(f"ranges {r.shape} and altitude {alt.shape} do not match (rows, cols) / (rows,)")
    if len(alt) < 2:
        return np.zeros_like(r)
    return r * beam_gaps(alt)[:, None]


def noise_regime(ranges: np.ndarray, altitude: np.ndarray, baseline: float) -> np.ndarray:
    """Returns (``ranges > 0``) whose :func:`column_spacing` is under ``baseline``: where the
    paper's successive steps up a column measure the range noise rather than the surface."""
    return (np.asarray(ranges) > 0) & (column_spacing(ranges, altitude) < baseline)


def ring_surface(
    xyz: np.ndarray,
    valid: np.ndarray,
    ranges: np.ndarray,
    baseline: float,
    max_turn_deg: float,
    at: np.ndarray | None = None,
    max_offset: int = 4,
) -> np.ndarray:
    """Per slot: whether the return lies on a smooth surface along its ring (Sec. 3's line
    statistic turned along the ring): the steps to the nearest returns at least ``k`` columns before
    and after it turn by less than ``max_turn_deg``, with ``k`` the fewest columns that put them at
    least ``baseline`` apart (``range x`` the column step; closer returns differ by their range
    noise); missing returns between are skipped (the paper's M state: dark paint, glass), over at
    most ``max_offset`` columns each way, and both steps must be shorter than three times the
    spacing of the columns they span (one surface, no edge between them). Rows are rings; the
    columns wrap around.

    Parameters
    ----------
    xyz : ndarray, shape (rows, cols, 3)
    valid : ndarray of bool, shape (rows, cols)
    ranges : ndarray, shape (rows, cols)
    baseline : float
        Least step (m), e.g. :func:`noise_baseline` of the sweep's range noise.
    max_turn_deg : float
    at : ndarray of bool, shape (rows, cols), or a pair of index arrays (rows, columns), optional
        Only these slots are tested (the others are False).
    max_offset : int

    Returns
    -------
    ndarray of bool, shape (rows, cols)
    """
    rows, cols = valid.shape
    if xyz.shape != (rows, cols, 3) or ranges.shape != (rows, cols):
        raise ValueError(f"xyz {xyz.shape}, valid {valid.shape} and ranges {ranges.shape} do not match")
    if max_offset < 1:
        raise ValueError(f"max_offset must be >= 1, got {max_offset}")
    out = np.zeros((rows, cols), bool)
    if isinstance(at, tuple):
        r, c = (np.asarray(a, dtype=np.int64) for a in at)
    else:
        r, c = np.nonzero(valid if at is None else (valid & at))
    if len(r) == 0:
        return out
    out[r, c] = ring_smooth_at(
        xyz, valid, ranges, float(baseline), float(np.cos(np.radians(max_turn_deg))), r, c, int(max_offset)
    )
    return out


@njit(cache=True, nogil=True)
def ring_smooth_at(xyz, valid, ranges, baseline, cos_turn, r, c, max_offset):
    """:func:`ring_surface` of the slots ``(r[i], c[i])`` (False where no return), one pass with no
    temporaries; ``cos_turn``: the cosine of ``max_turn_deg``.

    The arithmetic is that of the vectorised form it replaced, operation for operation (ranges and
    coordinates taken to float64 first; each norm summed x, y, z in order; the dot product of the
    two steps summed as numpy's ``einsum`` sums three products, the x and z terms first), so that
    both give the same bits."""
    cols = valid.shape[1]
    n = r.shape[0]
    out = np.zeros(n, np.bool_)
    ring_step = 2.0 * np.pi / cols
    for i in range(n):
        ri, ci = r[i], c[i]
        if not valid[ri, ci]:
            continue
        step = np.float64(ranges[ri, ci]) * ring_step
        k = int(min(max(np.ceil(baseline / max(step, 1e-9)), 1.0), float(max_offset)))
        before = 0  # the nearest valid return at least k columns away on each side
        for j in range(k, max_offset + 1):
            if valid[ri, (ci - j) % cols]:
                before = j
                break
        after = 0
        for j in range(k, max_offset + 1):
            if valid[ri, (ci + j) % cols]:
                after = j
                break
        if before == 0 or after == 0:
            continue
        cb, ca = (ci - before) % cols, (ci + after) % cols
        p0, p1, p2 = np.float64(xyz[ri, ci, 0]), np.float64(xyz[ri, ci, 1]), np.float64(xyz[ri, ci, 2])
        a0, a1, a2 = p0 - np.float64(xyz[ri, cb, 0]), p1 - np.float64(xyz[ri, cb, 1]), p2 - np.float64(xyz[ri, cb, 2])
        b0, b1, b2 = np.float64(xyz[ri, ca, 0]) - p0, np.float64(xyz[ri, ca, 1]) - p1, np.float64(xyz[ri, ca, 2]) - p2
        n1 = np.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
        n2 = np.sqrt((b0 * b0 + b1 * b1) + b2 * b2)
        if not (n1 < 3.0 * before * step and n2 < 3.0 * after * step and n1 > 0.0 and n2 > 0.0):
            continue
        cos = ((a0 * b0 + a2 * b2) + a1 * b1) / (n1 * n2)
        out[i] = cos > cos_turn
    return out


@njit(cache=True, nogil=True)
def coarse_vegetation_spacing(codes, ground, ranges, gap, max_spacing, vegetation):
    """The returns whose coarse class ``codes`` is ``vegetation`` (other than ``ground``) with a
    column spacing (``range x gap`` of their row, :func:`column_spacing`) under ``max_spacing``:
    their flat slot indices in image order and those spacings, in one pass over the image."""
    rows, cols = codes.shape
    slots = np.empty(rows * cols, np.int64)
    spacing = np.empty(rows * cols)
    m = 0
    for r in range(rows):
        g = gap[r]
        for c in range(cols):
            if codes[r, c] != vegetation or ground[r, c]:
                continue
            s = np.float64(ranges[r, c]) * g
            if s < max_spacing:
                slots[m] = r * cols + c
                spacing[m] = s
                m += 1
    return slots[:m].copy(), spacing[:m].copy()


@njit(cache=True, nogil=True)
def column_runs(lines, rank, slots, margin):
    """The runs of the columns of ``slots`` (flat indices of a ``rows x cols`` image, ``cols`` the
    number of ``lines``: a spinning sensor's scan line ``i`` is its column ``i``, lowest beam first,
    ``rank`` each row's position in it) from ``margin`` beams below the lowest of those slots in the
    column to as many above the highest, ``-1``-padded, in column order."""
    rows = rank.shape[0]
    cols = lines.shape[0]
    lo = np.full(cols, rows, np.int64)
    hi = np.full(cols, -1, np.int64)
    for s in slots:
        c = s % cols
        pos = rank[s // cols]
        lo[c] = min(lo[c], pos)
        hi[c] = max(hi[c], pos)
    n = 0
    width = 0
    for c in range(cols):
        if hi[c] >= 0:
            n += 1
            width = max(width, min(hi[c] + margin, rows - 1) - max(lo[c] - margin, 0) + 1)
    runs = np.full((n, width), -1, np.int64)
    i = 0
    for c in range(cols):
        if hi[c] < 0:
            continue
        a = max(lo[c] - margin, 0)
        b = min(hi[c] + margin, rows - 1)
        for t in range(b - a + 1):
            runs[i, t] = lines[c, a + t]
        i += 1
    return runs


@njit(cache=True, nogil=True)
def labelled_over_spacing(labels, ranges, gap, min_spacing, code):
    """Flat indices (image order) of the slots labelled ``code`` whose column spacing (``range x gap``
    of their row) exceeds ``min_spacing`` (every such slot when ``min_spacing <= 0``)."""
    rows, cols = labels.shape
    out = np.empty(rows * cols, np.int64)
    m = 0
    for r in range(rows):
        g = gap[r]
        for c in range(cols):
            if labels[r, c] != code:
                continue
            if min_spacing > 0.0 and not np.float64(ranges[r, c]) * g > min_spacing:
                continue
            out[m] = r * cols + c
            m += 1
    return out[:m].copy()
