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
from prc_slam.online.coarse import CoarseResult, LineReturns
from prc_slam.scan import Scan
from prc_slam.util.threads import in_threads

HISTORY = 500
#: numba's quicksort: partitions under this many samples are insertion-sorted (:func:`argsort_into`)
SMALL_SORT = 15
#: pending partitions :func:`argsort_into` can hold (numba's bound; the smaller side is sorted first, so
#: at most log2 of the length are pending)
ARGSORT_STACK = 100


@njit(cache=True, nogil=True)
def _track_mode(z, n, start, bandwidth):
    """Mean shift (flat kernel) from ``start`` over ``z[:n]``: the mode it climbs to.

    Each window's sum runs in four interleaved partial sums (samples ``j mod 4``), added
    pairwise at the end: one long chain of dependent additions was the cost of the ground's
    per-line update of ``z_d`` over its 500 estimates."""
    m = start
    for _ in range(100):
        s0 = s1 = s2 = s3 = 0.0
        c = 0
        n4 = n - n % 4
        for j in range(0, n4, 4):
            v0, v1, v2, v3 = z[j], z[j + 1], z[j + 2], z[j + 3]
            if abs(v0 - m) <= bandwidth:
                s0 += v0
                c += 1
            if abs(v1 - m) <= bandwidth:
                s1 += v1
                c += 1
            if abs(v2 - m) <= bandwidth:
                s2 += v2
                c += 1
            if abs(v3 - m) <= bandwidth:
                s3 += v3
                c += 1
        for j in range(n4, n):
            if abs(z[j] - m) <= bandwidth:
                s0 += z[j]
                c += 1
        if c == 0:
            return m
        new = ((s0 + s1) + (s2 + s3)) / c
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
def _potential_ground(codes, phi, first, run_len, phi_bw, srt, rank, cnt, tot, order, stack):
    """Part (a) on the returns ``first..`` of one line: (start, end) of the potential-ground run
    (end exclusive) or (-1, -1). ``srt, rank, cnt, tot, order, stack``: scratch of :func:`_grow_single_mode`
    (:func:`ground_scratch`)."""
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
    end_max = start + run_len  # points start..end-1 (n = 9 in the paper's 1-based terms)
    while end_max < n and codes[end_max] == 68:
        end_max += 1
    # rank growing blocks (x4) so that a run failing early costs little
    end, block = start + run_len, 4 * run_len
    while True:
        stop = min(end_max, start + block)
        end = _grow_single_mode(phi, start, end, stop, phi_bw, srt, rank, cnt, tot, order, stack)
        if end < stop or stop == end_max:
            return start, end
        block *= 4


@njit(cache=True, nogil=True)
def _fenwick_add(tree, i, v):
    i += 1
    while i < tree.shape[0]:
        tree[i] += v
        i += i & -i


@njit(cache=True, nogil=True)
def _fenwick_sum(tree, i):
    """Sum of the first ``i`` entries."""
    s = 0.0
    while i > 0:
        s += tree[i]
        i -= i & -i
    return s


@njit(cache=True, nogil=True, inline="always")
def _fenwick_sums(tree_a, tree_b, i):
    """:func:`_fenwick_sum` of two trees of one length over the first ``i`` entries, in one walk (each sum
    adds the same entries in the same order as on its own)."""
    a = 0.0
    b = 0.0
    while i > 0:
        a += tree_a[i]
        b += tree_b[i]
        i -= i & -i
    return a, b


@njit(cache=True, nogil=True)
def _track_mode_ranked(srt, cnt, tot, start, bandwidth):
    """:func:`_track_mode` over the samples entered in the Fenwick trees ``cnt`` / ``tot``
    (indexed by rank in ``srt``): each window sum is two binary searches and four prefix sums."""
    m = start
    for _ in range(100):
        i0 = np.searchsorted(srt, m - bandwidth, side="left")
        i1 = np.searchsorted(srt, m + bandwidth, side="right")
        # the window of :func:`_track_mode` exactly (|z - m| <= bandwidth, which m -+ bandwidth
        # rounded can miss by one sample at the edge)
        while i0 > 0 and abs(srt[i0 - 1] - m) <= bandwidth:
            i0 -= 1
        while i0 < srt.shape[0] and abs(srt[i0] - m) > bandwidth:
            i0 += 1
        while i1 < srt.shape[0] and abs(srt[i1] - m) <= bandwidth:
            i1 += 1
        while i1 > i0 and abs(srt[i1 - 1] - m) > bandwidth:
            i1 -= 1
        c1, t1 = _fenwick_sums(cnt, tot, i1)
        c0, t0 = _fenwick_sums(cnt, tot, i0)
        c = c1 - c0
        if c <= 0.0:
            return m
        new = (t1 - t0) / c
        if abs(new - m) < 1e-3 * bandwidth:
            return new
        m = new
    return m


@njit(cache=True, nogil=True)
def grow_single_mode(x, start, end, end_max, bandwidth):
    """Grow ``x[start:end]`` one sample at a time up to ``end_max`` while mean shift finds a
    single mode (:func:`single_mode` of ``x[start:e + 1]`` for ``e = end, end + 1, ...``);
    returns the first ``e`` that fails, or ``end_max``.

    Same answer as calling :func:`single_mode` on every prefix, in O(log n) per step instead
    of O(n): the candidates are ranked once, and the samples entered so far live in two
    Fenwick trees (count and sum) over those ranks. Samples spanning at most one bandwidth
    need no search: every window then holds all of them, so both ends climb to their mean.
    """
    return _grow_single_mode(x, start, end, end_max, bandwidth, *ground_scratch(max(0, end_max - start)))


@njit(cache=True, nogil=True)
def ground_scratch(width):
    """Scratch arrays for :func:`_grow_single_mode` over at most ``width`` samples (``srt, rank, cnt, tot,
    order, stack``), made once for many lines."""
    return (
        np.empty(width), np.empty(width, np.int64), np.empty(width + 1), np.empty(width + 1),
        np.empty(width, np.int64), np.empty((ARGSORT_STACK, 2), np.int64),
    )  # fmt: skip


@njit(cache=True, nogil=True, inline="always")
def _lt(a, b):
    """numba's order of floats in its sorts: NaN last."""
    return a < b or (np.isnan(b) and not np.isnan(a))


@njit(cache=True, nogil=True)
def _insertion_argsort(a, idx, low, high):
    """numba's quicksort's insertion sort of ``idx[low:high + 1]`` by ``a`` (bounds inclusive)."""
    for i in range(low + 1, high + 1):
        k = idx[i]
        v = a[k]
        j = i
        while j > low and _lt(v, a[idx[j - 1]]):
            idx[j] = idx[j - 1]
            j -= 1
        idx[j] = k


@njit(cache=True, nogil=True)
def _partition_argsort(a, idx, low, high):
    """numba's quicksort's partition of ``idx[low:high + 1]`` by ``a`` around the median of three; returns
    the pivot's place."""
    mid = (low + high) >> 1
    if _lt(a[idx[mid]], a[idx[low]]):
        idx[low], idx[mid] = idx[mid], idx[low]
    if _lt(a[idx[high]], a[idx[mid]]):
        idx[high], idx[mid] = idx[mid], idx[high]
    if _lt(a[idx[mid]], a[idx[low]]):
        idx[low], idx[mid] = idx[mid], idx[low]
    pivot = a[idx[mid]]
    idx[high], idx[mid] = idx[mid], idx[high]
    i = low
    j = high - 1
    while True:
        while i < high and _lt(a[idx[i]], pivot):
            i += 1
        while j >= low and _lt(pivot, a[idx[j]]):
            j -= 1
        if i >= j:
            break
        idx[i], idx[j] = idx[j], idx[i]
        i += 1
        j -= 1
    idx[i], idx[high] = idx[high], idx[i]
    return i


@njit(cache=True, nogil=True)
def argsort_into(a, idx, stack):
    """``np.argsort(a)`` as numba computes it in a kernel (its quicksort: the same permutation, ties and
    NaNs included) written into ``idx[:len(a)]``, with ``stack`` (``ARGSORT_STACK x 2`` int64) for its
    pending partitions: no array made per call (the ground's part (a) sorts the line angles of every
    scan line's run; the allocation cost as much as the sort)."""
    n = a.shape[0]
    for i in range(n):
        idx[i] = i
    if n < 2:
        return
    stack[0, 0] = 0
    stack[0, 1] = n - 1
    top = 1
    while top > 0:
        top -= 1
        low, high = stack[top, 0], stack[top, 1]
        while high - low >= SMALL_SORT:  # partition until an insertion sort is cheaper
            i = _partition_argsort(a, idx, low, high)
            if high - i > i - low:  # the larger side waits on the stack
                if high > i:
                    stack[top, 0], stack[top, 1] = i + 1, high
                    top += 1
                high = i - 1
            else:
                if i > low:
                    stack[top, 0], stack[top, 1] = low, i - 1
                    top += 1
                low = i + 1
        if high > low:
            _insertion_argsort(a, idx, low, high)


@njit(cache=True, nogil=True)
def _grow_single_mode(x, start, end, end_max, bandwidth, srt_buf, rank, cnt_buf, tot_buf, order_buf, stack):
    """:func:`grow_single_mode` with scratch arrays of at least ``end_max - start`` (+ 1) entries
    (:func:`ground_scratch`)."""
    if end >= end_max:
        return end_max
    vals = x[start:end_max]
    nv = vals.shape[0]
    # the ranks and the Fenwick trees are made when the samples first spread over more than one bandwidth (a
    # line whose samples never do needs neither), the samples so far entered then in order: the same trees
    ranked = 0  # samples entered in the trees
    srt = srt_buf[:nv]
    cnt = cnt_buf[: nv + 1]
    tot = tot_buf[: nv + 1]
    lo = np.inf
    hi = -np.inf
    for e in range(nv):
        v = vals[e]
        lo = min(lo, v)
        hi = max(hi, v)
        if e + start < end or hi - lo <= bandwidth:  # within one bandwidth: a single mode
            continue
        if ranked == 0:
            argsort_into(vals, order_buf, stack)
            for i in range(nv):
                srt[i] = vals[order_buf[i]]
                rank[order_buf[i]] = i
            cnt[:] = 0.0
            tot[:] = 0.0
        while ranked <= e:
            _fenwick_add(cnt, rank[ranked], 1.0)
            _fenwick_add(tot, rank[ranked], vals[ranked])
            ranked += 1
        a = _track_mode_ranked(srt, cnt, tot, lo, bandwidth)
        b = _track_mode_ranked(srt, cnt, tot, hi, bandwidth)
        if abs(b - a) >= bandwidth / 2:
            return e + start
    return end_max


@njit(cache=True, nogil=True)
def _lowest_mean(z, k):
    """The mean of the ``k`` lowest of ``z`` (all if fewer), summed from the lowest up: the value
    of ``np.sort(z)[:k].mean()``, without sorting the rest."""
    return _lowest_mean_into(z, k, np.empty(min(k, z.shape[0])))


@njit(cache=True, nogil=True)
def _lowest_mean_into(z, k, low):
    """:func:`_lowest_mean` with ``low`` (at least ``min(k, len(z))`` entries) as its scratch: no array
    made per call (one call per scan line with a potential-ground run)."""
    m = min(k, z.shape[0])
    n = 0
    for v in z:  # insertion into the m lowest so far, ascending
        if n == m and not v < low[m - 1]:
            continue
        j = min(n, m - 1)
        while j > 0 and v < low[j - 1]:
            low[j] = low[j - 1]
            j -= 1
        low[j] = v
        n = min(n + 1, m)
    s = 0.0
    for j in range(m):
        s += low[j]
    return s / m


@njit(cache=True, nogil=True)
def first_runs(codes, phi, count, lo, hi, run_len, phi_bw, run_a, run_b):
    """Part (a) from the start of lines ``lo..hi - 1`` (their returns in the rows of ``codes,
    phi``, ``count`` each): the first potential-ground run ``(run_a, run_b)`` of each line
    (-1, -1: none).

    It does not depend on ``z_d``: this bulk of the ground algorithm's work is done for all lines
    independently (in threads, :func:`all_first_runs`) before the sequential pass of part (b),
    :func:`ground_lines`."""
    scratch = ground_scratch(codes.shape[1])
    for li in range(lo, hi):
        m = count[li]
        run_a[li], run_b[li] = _potential_ground(codes[li, :m], phi[li, :m], 0, run_len, phi_bw, *scratch)


def all_first_runs(returns: LineReturns, run_len: int, phi_bw: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`first_runs` of every line of ``returns``, the lines split between the numba threads."""
    n = returns.count.shape[0]
    run_a, run_b = np.empty(n, np.int64), np.empty(n, np.int64)
    in_threads(
        lambda lo, hi: first_runs(returns.codes, returns.phi, returns.count, lo, hi, run_len, phi_bw, run_a, run_b), n
    )
    return run_a, run_b


@njit(cache=True, nogil=True)
def ground_lines(
    n_slots,
    pts_all,
    codes_all,
    phi_all,
    zs_all,
    count,
    run_a,
    run_b,
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
    """Parts (a) and (b) over all lines of a frame (their returns, :class:`LineReturns`, and
    first potential-ground runs, :func:`first_runs`), continuing the state ``(z_hist, n_hist, zd, have_zd)``.
    Returns the ground mask of the ``n_slots`` slots, the per-line ground height and the state."""
    n_lines = count.shape[0]
    ground = np.zeros(n_slots, np.bool_)
    line_height = np.full(n_lines, np.nan)
    pending = np.zeros(n_lines, np.bool_)  # lines seen before z_d existed
    scratch = ground_scratch(pts_all.shape[1])
    low5 = np.empty(5)  # _lowest_mean_into's
    for li in range(n_lines):
        m = count[li]
        pts = pts_all[li, :m]
        codes = codes_all[li, :m]
        phi = phi_all[li, :m]
        zs = zs_all[li, :m]
        first = 0
        while True:
            if first == 0:
                a, b = run_a[li], run_b[li]
            else:
                a, b = _potential_ground(codes, phi, first, run_len, phi_bw, *scratch)
            if a < 0:
                break
            zi = _lowest_mean_into(zs[a:b], 5, low5)
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
        if have_zd and np.isnan(line_height[li]):
            line_height[li] = zd  # no ground on this line: the last updated estimate
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
        self.line_heights: np.ndarray | None = None

    @property
    def height(self) -> float | None:
        """The dominant ground height ``z_d`` (sensor frame), once known."""
        return self.zd if self.have_zd else None

    def _run(
        self, n_slots: int, returns: LineReturns, runs: tuple[np.ndarray, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`ground_lines` on the lines of ``returns`` (first runs ``runs``) from the current
        state; updates the state."""
        p = self.params
        ground, heights, pending, self.z_hist, self.n_hist, self.zd, self.have_zd = ground_lines(
            n_slots, *returns.arrays(), *runs, self.z_hist, self.n_hist, self.zd, self.have_zd,
            p.run_len, p.phi_bandwidth, p.z_bandwidth, p.rel_tolerance, p.grow_tolerance, p.n_init,
        )  # fmt: skip
        return ground, heights, pending

    def process(self, scan: Scan, coarse: CoarseResult) -> np.ndarray:
        """Ground mask (rows, cols) of one scan, given its coarse classification. Afterwards
        :attr:`line_heights` holds the ground height of each of the scan's lines."""
        p = self.params
        n_slots = scan.valid.size
        returns = coarse.returns
        run_a, run_b = all_first_runs(returns, p.run_len, p.phi_bandwidth)
        had = self.have_zd
        ground, heights, pending = self._run(n_slots, returns, (run_a, run_b))
        if self.have_zd and not had and pending.any():  # start again from the first scan line
            again, heights[pending], _ = self._run(n_slots, returns.subset(pending), (run_a[pending], run_b[pending]))
            ground |= again
        self.line_heights = np.where(np.isnan(heights), self.zd, heights) if self.have_zd else None
        assert L.HORIZONTAL == 68  # code tested by the kernel
        return ground.reshape(scan.shape)
