"""Scan lines and the coarse online classifier of Stamos et al. (paper 001), Sec. 3, 4, 7.1.

Every return of a scan line is classified as horizontal (H), vertical (V) or vegetation (T):
vegetation by an online CUSUM between two hidden Markov models over the signed angles ``sV``
(slow vs fast transitions between Gaussian states at -90, 0 and 90 deg, Sec. 4), horizontal
vs vertical by an online CUSUM on a 90 deg change of the mean of ``sV`` among the other
points. The less sensitive vegetation detector T' (Sec. 7.1) runs the same CUSUM on the
differences ``sD = sV_k - sV_{k-1}`` with the paper's transition matrices and ``h = 10``.

Sec. 4 takes the slow/fast models and the H/V CUSUM from its reference [7], which gives no
numbers here; the values below (``CoarseParams``) are ours and are exercised by the tests.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from prc_slam import labels as L
from prc_slam.online import kernels as K
from prc_slam.scan import ProfilerSensor, Scan, SpinningSensor
from prc_slam.util.threads import in_threads

PROFILER_START_RADIUS = 10.0  # m, see scan_lines


def _uniform3() -> np.ndarray:
    return np.full((3, 3), 1.0 / 3.0)


@dataclass(frozen=True)
class CoarseParams:
    """Parameters of the coarse classifier and of T'."""

    veg_means: tuple[float, float, float] = (-90.0, 0.0, 90.0)
    veg_sigma: float = 20.0
    veg_slow: np.ndarray = field(default_factory=lambda: np.full((3, 3), 0.05) + np.eye(3) * 0.85)
    veg_fast: np.ndarray = field(default_factory=_uniform3)
    veg_h: float = 10.0
    hv_sigma: float = 25.0
    hv_h: float = 5.0
    # Sec. 7.1: under H0 every row is (0.1, 0.8, 0.1), under H1 all 1/3; h = 10
    tp_means: tuple[float, float, float] = (-150.0, 0.0, 150.0)
    tp_sigma: float = 40.0
    tp_regular: np.ndarray = field(default_factory=lambda: np.tile([0.1, 0.8, 0.1], (3, 1)))
    tp_fast: np.ndarray = field(default_factory=_uniform3)
    tp_h: float = 10.0
    min_step: float = 0.0  # beyond the paper: minimum baseline of D_k (m), see line_statistics
    centred: bool = False  # with min_step: the baseline centred on X_k, see line_statistics


def scan_lines(scan: Scan, start_radius: float = PROFILER_START_RADIUS) -> np.ndarray:
    """The paper's scan lines as rows of flat slot indices (``-1`` pads), ``int64[L, n]``.

    Spinning sensor: one line per column, read from the lowest beam up. Profiler: each scan
    line read outwards from its lowest return within ``start_radius`` (horizontal distance from
    the scanner; the lowest of all if none lies that close) in both directions, two lines per
    row (rows ``0..R-1`` up, ``R..2R-1`` down) which share only that first return; per-slot
    results take the down line's (see :func:`shared_first`).

    The radius is ours: where the terrain falls away beside the street, the lowest return of a
    line lies far across it, and the ground run found there is rejected by the 10 % test, so
    the street itself went unlabelled (ground recall 0.38 on one simulated street, 0.73 with it).
    """
    rows, cols = scan.shape
    if isinstance(scan.sensor, SpinningSensor):
        return _column_lines(rows, cols, np.asarray(scan.sensor.altitude, dtype=np.float64).tobytes())
    flat = np.arange(rows * cols).reshape(rows, cols)
    if isinstance(scan.sensor, ProfilerSensor):
        xyz = scan.slot_xyz()
        near = scan.valid & (np.hypot(xyz[..., 0], xyz[..., 1]) <= start_radius)
        far_only = ~near.any(axis=1)
        near[far_only] = scan.valid[far_only]
        low = np.argmin(np.where(near, xyz[..., 2], np.inf), axis=1)
        half = cols // 2 + 1  # up: the lowest return and the next half - 1; down: it and the rest
        step = np.arange(half)
        up = flat[np.arange(rows)[:, None], (low[:, None] + step[None, :]) % cols]
        down = flat[np.arange(rows)[:, None], (low[:, None] - step[None, :]) % cols]
        down[:, cols - half + 1 :] = -1
        return np.concatenate([up, down])
    raise TypeError(f"no scan-line definition for {type(scan.sensor).__name__}")


@functools.lru_cache(maxsize=16)
def _column_lines(rows: int, cols: int, altitude: bytes) -> np.ndarray:
    """A spinning sensor's scan lines (:func:`scan_lines`), made once per sensor layout
    (read-only: every scan of a stream shares them)."""
    order = np.argsort(np.frombuffer(altitude, dtype=np.float64), kind="stable")
    lines = np.ascontiguousarray(np.arange(rows * cols).reshape(rows, cols)[order].T)
    lines.flags.writeable = False
    return lines


def elevation_rows(altitude: np.ndarray) -> slice | np.ndarray:
    """Row index that puts a spinning sensor's rows in elevation order, lowest beam first: a
    slice (a view) when the rows already are in elevation order or in its reverse, as most
    readers give them; else the stable argsort of ``altitude`` (read-only; made once per
    sensor layout)."""
    return _elevation_rows(np.asarray(altitude, dtype=np.float64).tobytes())


@functools.lru_cache(maxsize=16)
def _elevation_rows(altitude: bytes) -> slice | np.ndarray:
    order = np.argsort(np.frombuffer(altitude, dtype=np.float64), kind="stable")
    rows = len(order)
    if (order == np.arange(rows)).all():
        return slice(None)
    if (order == np.arange(rows)[::-1]).all():
        return slice(None, None, -1)
    order.flags.writeable = False
    return order


def line_values(value: float | np.ndarray, n_lines: int) -> np.ndarray:
    """A per-line quantity (e.g. the ground height) as ``float64[n_lines]``, from one value
    for every line or one per line."""
    out = np.broadcast_to(np.asarray(value, dtype=np.float64), (n_lines,))
    if not np.isfinite(out).all():
        raise ValueError("per-line values must be finite")
    return np.ascontiguousarray(out)


def shared_first(scan: Scan) -> int:
    """How many leading lines of :func:`scan_lines` share their first slot with a later line
    (a profiler's up lines); kernels leave that slot's per-slot results to the later line, so
    that every slot is written once."""
    return scan.shape[0] if isinstance(scan.sensor, ProfilerSensor) else 0


@njit(cache=True, nogil=True)
def _classify_lines(
    codes, t_prime, sv_out, phi_out, ret_pts, ret_codes, ret_phi, ret_z, ret_count, lo, hi,
    xyz, valid, lines, vm, vs, va0, va1, vh, hs, hh, tm, ts, ta0, ta1, th, min_step, centred, shared, with_tp,
):  # fmt: skip
    """The coarse classes of lines ``lo..hi - 1`` written into ``codes, t_prime, sv_out, phi_out``
    (per slot) and each line's returns into the rows of ``ret_*`` (:class:`LineReturns`).

    Per-line arrays live in buffers made once per call, not once per line."""
    origin = np.zeros(3)
    width = lines.shape[1]
    sv_b, phi_b = np.empty(width), np.empty(width)
    veg_b, tp_b, vert_b = np.empty(width, np.bool_), np.empty(width, np.bool_), np.empty(width, np.bool_)
    sd_b, rest_b = np.empty(width), np.empty(width)
    work = np.empty((2, width))
    for li in range(lo, hi):  # scan lines are independent; each writes only its slots
        pts = ret_pts[li]
        n = K.line_statistics_into(xyz, valid, lines[li], origin, min_step, centred, pts, sv_b, phi_b, work)
        ret_count[li] = n
        if n == 0:
            continue
        sv, phi = sv_b[:n], phi_b[:n]
        veg = veg_b[:n]
        if vm.shape[0] == 3:
            K.hmm_cusum3_into(sv, vm, vs, va0, va1, vh, veg)
        else:
            veg[:] = K.hmm_cusum(sv, vm, vs, va0, va1, vh)
        tp = tp_b[:n]
        if with_tp:
            sd = sd_b[:n]
            sd[0] = 0.0
            for k in range(1, n):
                sd[k] = sv[k] - sv[k - 1]
            if tm.shape[0] == 3:
                K.hmm_cusum3_into(sd, tm, ts, ta0, ta1, th, tp)
            else:
                tp[:] = K.hmm_cusum(sd, tm, ts, ta0, ta1, th)
        m = 0
        for k in range(n):
            if not veg[k]:
                rest_b[m] = sv[k]
                m += 1
        vertical = vert_b[:m]
        K.mean_shift_cusum_into(rest_b[:m], 90.0, 0.0, hs, hh, vertical)
        j = 0
        for k in range(n):
            s = pts[k]
            code = 5
            if not veg[k]:
                code = 69 if vertical[j] else 68
                j += 1
            ret_codes[li, k] = code
            ret_phi[li, k] = np.float64(np.float32(phi[k]))  # as stored per slot
            ret_z[li, k] = xyz[s, 2]
            if k == 0 and li < shared and s == lines[li, 0]:  # the down line writes it
                continue
            sv_out[s] = sv[k]
            phi_out[s] = phi[k]
            if with_tp:
                t_prime[s] = tp[k]
            codes[s] = code


@dataclass
class LineReturns:
    """Every scan line's returns in contiguous rows, in line order: slots ``pts``, coarse
    ``codes``, line angles ``phi`` (the per-slot float32 values), heights ``z``; ``count`` per
    line (the rest of a row is unused). The later stages read a line's returns from here."""

    pts: np.ndarray  # int64 (lines, width)
    codes: np.ndarray  # uint8 (lines, width)
    phi: np.ndarray  # float64 (lines, width)
    z: np.ndarray  # float64 (lines, width)
    count: np.ndarray  # int64 (lines,)

    @classmethod
    def empty(cls, n_lines: int, width: int) -> LineReturns:
        return cls(
            np.empty((n_lines, width), np.int64), np.empty((n_lines, width), np.uint8),
            np.empty((n_lines, width)), np.empty((n_lines, width)), np.empty(n_lines, np.int64),
        )  # fmt: skip

    def arrays(self) -> tuple[np.ndarray, ...]:
        return self.pts, self.codes, self.phi, self.z, self.count

    def subset(self, lines: np.ndarray) -> LineReturns:
        """The rows of ``lines`` (a mask or indices)."""
        return LineReturns(*(a[lines] for a in self.arrays()))


@dataclass
class CoarseResult:
    """Per-slot results: ``codes`` (68 horizontal, 69 vertical, 5 vegetation, 0 no return),
    ``t_prime`` (less sensitive vegetation, Sec. 7.1; None when not asked for: only the per-column
    car algorithm of Sec. 7 uses it), signed angles ``sv`` and line angles ``phi_hat``; the
    scan lines they were computed on (:func:`scan_lines`), which the later stages use, and
    each line's ``returns`` (:class:`LineReturns`)."""

    codes: np.ndarray
    t_prime: np.ndarray | None
    sv: np.ndarray
    phi_hat: np.ndarray
    lines: np.ndarray
    returns: LineReturns


def _shared_returns(returns: LineReturns, lines: np.ndarray, shared: int, codes: np.ndarray, phi: np.ndarray) -> None:
    """The first return of each of the ``shared`` leading lines takes the classes its slot got
    from the later line that writes it (:func:`shared_first`), as every stage reads them per slot."""
    if shared == 0:
        return
    first = returns.pts[:shared, 0]
    own = np.flatnonzero((returns.count[:shared] > 0) & (first == lines[:shared, 0]))
    returns.codes[own, 0] = codes[first[own]]
    returns.phi[own, 0] = phi[first[own]]


def coarse_classify(
    scan: Scan,
    params: CoarseParams | None = None,
    t_prime: bool = True,
    only: np.ndarray | None = None,
    lines: np.ndarray | None = None,
) -> CoarseResult:
    """Run the coarse H / V / T classifier and (``t_prime``) T' on every scan line of ``scan``.

    Without ``t_prime`` the result's ``t_prime`` is None: one CUSUM per return less (the
    spinning-sensor path, :mod:`prc_slam.online.spinning`, does not use T'). ``only`` (a mask
    over :func:`scan_lines`; spinning sensors): classify those lines alone, the slots of the
    others keep code 0 (the result's ``lines`` and ``returns`` are those lines'). ``lines``
    (spinning sensors): classify these ``-1``-padded runs of slots instead of the scan lines (parts
    of columns, lowest beam first), the other slots keep code 0."""
    p = params or CoarseParams()
    xyz = scan.slot_xyz64()
    valid = scan.valid.ravel()
    if lines is not None:
        if shared_first(scan) or only is not None:
            raise ValueError(f"{scan.source}: coarse_classify(lines=...) needs lines that share no slot, and no only")
        lines = np.ascontiguousarray(lines, dtype=np.int64)
        if lines.ndim != 2 or (lines >= valid.shape[0]).any():
            raise ValueError(f"lines must be (n, width) slot indices under {valid.shape[0]}, got shape {lines.shape}")
    else:
        lines = scan_lines(scan)
    if only is not None:
        if shared_first(scan):
            raise ValueError(f"{scan.source}: coarse_classify(only=...) needs lines that share no slot")
        only = np.asarray(only, dtype=bool)
        if only.shape != (len(lines),):
            raise ValueError(f"only: one flag per scan line ({len(lines)}), got shape {only.shape}")
        lines = lines[only]
    n_slots = xyz.shape[0]
    codes = np.zeros(n_slots, np.uint8)
    tp = np.zeros(n_slots, np.bool_)
    sv = np.zeros(n_slots, np.float32)
    phi = np.zeros(n_slots, np.float32)
    args = (
        xyz, valid, lines,
        np.array(p.veg_means, float), p.veg_sigma, p.veg_slow, p.veg_fast, p.veg_h,
        p.hv_sigma, p.hv_h,
        np.array(p.tp_means, float), p.tp_sigma, p.tp_regular, p.tp_fast, p.tp_h,
        p.min_step, p.centred, shared_first(scan), t_prime,
    )  # fmt: skip
    returns = LineReturns.empty(*lines.shape)
    out = (codes, tp, sv, phi, *returns.arrays())
    in_threads(lambda lo, hi: _classify_lines(*out, lo, hi, *args), len(lines))
    _shared_returns(returns, lines, shared_first(scan), codes, phi)
    shape = scan.shape
    assert L.VEGETATION == 5 and L.HORIZONTAL == 68 and L.VERTICAL == 69  # codes used by the kernel
    tp = tp.reshape(shape) if t_prime else None
    return CoarseResult(codes.reshape(shape), tp, sv.reshape(shape), phi.reshape(shape), lines, returns)
