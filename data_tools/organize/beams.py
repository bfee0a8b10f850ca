"""The beam table: the sensor's beam elevations, found from the data, and each point's beam.

Clustering of elevation angles into the sensor's beams (peaks of a fine elevation histogram,
:func:`estimate_beams`) is the organiser's last way to rows, when the points carry no ring field
and no consistent order (:func:`rows_from_beams`); the table is estimated once per sequence (first
sweep) and reused, so row ``r`` is the same beam in every frame. The beam-origin offset
(:func:`estimate_beam_offset`) is found the same way: the offset that makes the histogram sharpest.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from data_tools.errors import DataError
from data_tools.organize.polar import fast_atan2
from prc_slam.util.threads import in_threads

#: beams method: share of points within a quarter beam gap of their beam below which the
#: elevations show no beam structure (uniform elevations give ~0.5)
MIN_BEAM_CONCENTRATION = 0.65
#: 0.005 deg bins over [-90, 90] deg (the elevation histogram of the beam-offset search)
ELEVATION_BINS = 36000


def beam_bounds(beam_te: np.ndarray) -> np.ndarray:
    """Interval bounds (tangent space, descending) between consecutive beams (sorted top first),
    at the mid-angle between them."""
    ang = np.arctan(beam_te)
    return np.tan(0.5 * (ang[:-1] + ang[1:]))


@njit(cache=True, nogil=True)
def nearest_beam(te, ok, bounds, row):
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
    beam_te = np.tan(np.radians(np.sort(centres)[::-1]))
    return beam_te, beam_concentration(te, beam_te)


def beam_concentration(te: np.ndarray, beam_te: np.ndarray) -> float:
    """Share of points within a quarter of the local beam gap (in angle) of their nearest beam."""
    if len(beam_te) < 2 or len(te) == 0:
        return 1.0 if len(beam_te) == 1 else 0.0
    ang = np.arctan(beam_te)  # descending
    el = np.arctan(te)
    row = nearest_beam(te, np.ones(len(te), bool), beam_bounds(beam_te), np.empty(len(te), np.int64))
    gaps = np.abs(np.diff(ang))
    local = np.empty(len(ang))
    local[0], local[-1] = gaps[0], gaps[-1]
    local[1:-1] = np.minimum(gaps[:-1], gaps[1:])
    inside = np.abs(el - ang[row]) <= 0.25 * local[row]
    return float(inside.mean())


def rows_from_beams(
    ok: np.ndarray,
    rng: np.ndarray,
    te: np.ndarray,
    beam_te: np.ndarray | None,
    concentration: float,
    expected: int | None,
    row: np.ndarray,
    source: str,
    warnings: list[str],
) -> tuple[np.ndarray, np.ndarray, float]:
    """Row of every point from the sequence's beam table (-1 for no-return points; written into
    ``row``), the table estimated on the first sweep (``beam_te`` None) and checked on the later
    ones (a warning when the sweep no longer fits it). Returns the rows, the table and its
    concentration on the first sweep.

    Raises
    ------
    DataError
        When the first sweep's elevations show no beam structure."""
    if beam_te is None:
        beam_te, concentration = estimate_beams(te[ok], rng[ok], expected)
        if len(beam_te) == 0:
            raise DataError(f"{source}: cannot organise: no beam structure in the elevations")
        if concentration < MIN_BEAM_CONCENTRATION and len(beam_te) > 1:
            raise DataError(
                f"{source}: cannot organise: the point elevations show no beam structure "
                f"(only {100 * concentration:.0f}% of points near one of {len(beam_te)} elevation peaks) and the "
                "points carry no ring field and no consistent order"
            )
    else:
        # does this sweep still fit the sequence's beam table? (checked on a sample)
        sub = slice(None, None, max(1, len(te) // 5000))  # a share: 5,000 points tell it to ~1 %
        conc = beam_concentration(te[sub][ok[sub]], beam_te)
        if conc < min(MIN_BEAM_CONCENTRATION, concentration - 0.15):
            warnings.append(
                f"{source}: only {100 * conc:.0f}% of the points lie near the beams found on the first sweep "
                f"({100 * concentration:.0f}% there): the beam table does not fit this sweep"
            )
    return nearest_beam(te, ok, beam_bounds(beam_te), row), beam_te, concentration


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

    The bins are first taken from :func:`~data_tools.organize.polar.fast_atan2` (within 2e-6 rad,
    2 % of a bin, without libm's arctan); the points within 5 % of a bin's edge are binned again
    with ``arctan``, so every bin is the one ``arctan`` gives."""
    bins = ELEVATION_BINS
    half = kernel.shape[0] // 2
    scale = 180.0 / np.pi / 0.005
    for i in range(z.shape[0]):
        u[i] = fast_atan2(z[i], rho[i] - n) * scale + 90.0 / 0.005
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
