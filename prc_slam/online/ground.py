"""The ground algorithm of Stamos et al. (paper 001), Sec. 5, parts (a) and (b).

(a) Within a scan line: the first 10 consecutive horizontal returns start a potential-ground
run, grown while the mean-shift of their line angles ``phi_hat`` keeps one mode and the next
return is horizontal; ``z_i`` is the mean of the 5 lowest of its points.
(b) Across scan lines: the dominant ground height ``z_d`` is the main mean-shift mode of the
first 50 estimates; a run whose ``|z_i - z_d| / |z_d| < 10 %`` becomes ground and grows over
the following horizontal, almost collinear returns; otherwise part (a) restarts after the run.
``z_d`` is then updated from every new estimate.

Not given by the paper, ours: mean-shift bandwidths (``phi_bandwidth`` 10 deg, ``z_bandwidth``
0.2 m), the collinearity tolerance of growing (``grow_tolerance`` 10 deg; 2-3 deg found 2 % of
the ground on a simulated profiler drive, whose cambered, rough road spreads ``phi_hat`` by several
degrees, 10 deg found 64 % at precision 0.99), and the update of
``z_d`` after the first 50 estimates, which follows the main mode by mean-shift iterations
started at the current ``z_d`` over the last 500 estimates instead of re-searching every mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from prc_slam import labels as L
from prc_slam.online import kernels as K
from prc_slam.online.coarse import CoarseResult, scan_lines
from prc_slam.scan import Scan

HISTORY = 500


@njit(cache=True, nogil=True)
def _track_mode(z, n, start, bandwidth):
    """Mean shift (flat kernel) from ``start`` over ``z[:n]``: the mode it climbs to."""
    m = start
    for _ in range(100):
        s = 0.0
        c = 0
        for j in range(n):
            if abs(z[j] - m) <= bandwidth:
                s += z[j]
                c += 1
        if c == 0:
            return m
        new = s / c
        if abs(new - m) < 1e-3 * bandwidth:
            return new
        m = new
    return m


@njit(cache=True, nogil=True)
def mean_shift_modes(x, bandwidth):
    """Modes of 1-D samples by mean shift with a flat kernel: every sample climbs to the mean
    of its ``bandwidth`` neighbourhood until it stops; converged points closer than
    ``bandwidth / 2`` are one mode. Returns (modes, sample counts) sorted by count, largest first."""
    n = x.shape[0]
    conv = np.empty(n)
    for i in range(n):
        conv[i] = _track_mode(x, n, x[i], bandwidth)
    order = np.argsort(conv)
    modes = np.empty(n)
    counts = np.zeros(n, np.int64)
    k = 0
    for idx in order:
        if k > 0 and abs(conv[idx] - modes[k - 1]) < bandwidth / 2:
            counts[k - 1] += 1
        else:
            modes[k] = conv[idx]
            counts[k] = 1
            k += 1
    modes = modes[:k]
    counts = counts[:k]
    rank = np.argsort(-counts, kind="mergesort")
    return modes[rank], counts[rank]


@njit(cache=True, nogil=True)
def single_mode(x, bandwidth):
    """Whether mean shift (flat kernel) finds one mode in ``x``. In 1-D the mean-shift map is
    monotone, so seeds keep their order: one mode exactly when the lowest and the highest
    sample converge to the same point (same answer as :func:`mean_shift_modes`, O(n) per
    iteration instead of O(n^2))."""
    lo = _track_mode(x, x.shape[0], x.min(), bandwidth)
    hi = _track_mode(x, x.shape[0], x.max(), bandwidth)
    return abs(hi - lo) < bandwidth / 2


@njit(cache=True, nogil=True)
def _potential_ground(codes, phi, zs, first, run_len, phi_bw):
    """Part (a) on the returns ``first..`` of one line: (start, end) of the potential-ground run
    (end exclusive) or (-1, -1)."""
    n = codes.shape[0]
    count = 0
    start = -1
    for k in range(first, n):
        if codes[k] == 68:
            count += 1
            if count == run_len:
                start = k - run_len + 1
                break
        else:
            count = 0
    if start < 0:
        return -1, -1
    end = start + run_len  # points start..end-1 (n = 9 in the paper's 1-based terms)
    while end < n and codes[end] == 68:
        if not single_mode(phi[start : end + 1], phi_bw):
            break
        end += 1
    return start, end


@njit(cache=True, nogil=True)
def _lowest_mean(z, k):
    s = np.sort(z)
    m = min(k, s.shape[0])
    return s[:m].mean()


@njit(cache=True, nogil=True)
def ground_lines(
    xyz,
    slot_codes,
    slot_phi,
    valid,
    lines,
    z_hist,
    n_hist,
    zd,
    have_zd,
    run_len,
    phi_bw,
    z_bw,
    rel_tol,
    grow_tol,
    n_init,
):
    """Parts (a) and (b) over all lines of a frame, continuing the state ``(z_hist, n_hist,
    zd, have_zd)``. Returns the ground mask per slot, the per-line ground height and the state."""
    n_slots = xyz.shape[0]
    ground = np.zeros(n_slots, np.bool_)
    line_height = np.full(lines.shape[0], np.nan)
    pending = np.zeros(lines.shape[0], np.bool_)  # lines seen before z_d existed
    for li in range(lines.shape[0]):
        pts = K.line_returns(lines[li], valid)
        m = pts.shape[0]
        codes = slot_codes[pts]
        phi = slot_phi[pts].astype(np.float64)
        zs = xyz[pts, 2]
        first = 0
        while True:
            a, b = _potential_ground(codes, phi, zs, first, run_len, phi_bw)
            if a < 0:
                break
            zi = _lowest_mean(zs[a:b], 5)
            if not have_zd:
                z_hist[n_hist % z_hist.shape[0]] = zi
                n_hist += 1
                pending[li] = True
                if n_hist >= n_init:
                    modes, _ = mean_shift_modes(z_hist[: min(n_hist, z_hist.shape[0])], z_bw)
                    zd = modes[0]
                    have_zd = True
                break
            if abs(zi - zd) < rel_tol * abs(zd):
                mean_phi = phi[a:b].mean()
                end = b
                while end < m and codes[end] == 68 and abs(phi[end] - mean_phi) < grow_tol:
                    end += 1
                for k in range(a, end):
                    ground[pts[k]] = True
                line_height[li] = zi
                z_hist[n_hist % z_hist.shape[0]] = zi
                n_hist += 1
                zd = _track_mode(z_hist, min(n_hist, z_hist.shape[0]), zd, z_bw)
                break
            first = b  # not close to z_d: part (a) again after the run
    return ground, line_height, pending, z_hist, n_hist, zd, have_zd


@dataclass
class GroundParams:
    run_len: int = 10
    phi_bandwidth: float = 10.0
    z_bandwidth: float = 0.2
    rel_tolerance: float = 0.10
    grow_tolerance: float = 10.0
    n_init: int = 50


class GroundDetector:
    """Streaming ground algorithm: keeps the ground-height estimates across frames.

    The lines seen before the first 50 estimates exist are processed again once ``z_d`` is
    known (the paper's "start again from the first scanline")."""

    def __init__(self, params: GroundParams | None = None) -> None:
        self.params = params or GroundParams()
        self.z_hist = np.zeros(HISTORY)
        self.n_hist = 0
        self.zd = 0.0
        self.have_zd = False

    @property
    def height(self) -> float | None:
        """The dominant ground height ``z_d`` (sensor frame), once known."""
        return self.zd if self.have_zd else None

    def _run(self, args: tuple, lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:func:`ground_lines` on ``lines`` from the current state; updates the state."""
        p = self.params
        ground, _, pending, self.z_hist, self.n_hist, self.zd, self.have_zd = ground_lines(
            *args, lines, self.z_hist, self.n_hist, self.zd, self.have_zd,
            p.run_len, p.phi_bandwidth, p.z_bandwidth, p.rel_tolerance, p.grow_tolerance, p.n_init,
        )  # fmt: skip
        return ground, pending

    def process(self, scan: Scan, coarse: CoarseResult) -> np.ndarray:
        """Ground mask (rows, cols) of one scan, given its coarse classification."""
        xyz = scan.slot_xyz().reshape(-1, 3).astype(np.float64)
        lines = scan_lines(scan)
        args = (xyz, coarse.codes.ravel(), coarse.phi_hat.ravel(), scan.valid.ravel())
        had = self.have_zd
        ground, pending = self._run(args, lines)
        if self.have_zd and not had and pending.any():  # start again from the first scan line
            ground |= self._run(args, lines[pending])[0]
        assert L.HORIZONTAL == 68  # code tested by the kernel
        return ground.reshape(scan.shape)
