"""Numba kernels of the online scan-line statistics (Stamos et al., Sec. 3, 4 and 7.1).

A scan line is given as a row of slot indices (``-1`` pads the end); slots without a return
are the paper's missing points M and are skipped by the statistics.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: ``g(z)`` of :func:`arccos` (``asin(s) = s + s z g(z)``, ``z = s^2`` in ``[0, 1/4]``), lowest
#: power first; fitted by ``scripts/fit_arccos.py`` (a refit's last digits follow the LAPACK kernels
#: the CPU selects; the tests bound the error of these coefficients, not their digits)
ARCCOS_G = (
    0.16666666666666657, 0.07500000000020912, 0.044642857102371265, 0.03038194745732771,
    0.02237204423740889, 0.01735533035745869, 0.013928767296575563, 0.011882537079030621,
    0.007767330166783341, 0.016146609393178146, -0.010943884401817565, 0.028316208443389522,
)  # fmt: skip
_G0, _G1, _G2, _G3, _G4, _G5, _G6, _G7, _G8, _G9, _G10, _G11 = ARCCOS_G
_PI_LO = 1.2246467991473532e-16  # pi - float(pi)
_PIO2_LO = 6.123233995736766e-17  # pi / 2 - float(pi / 2)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def arccos(c):
    """``arccos(c)`` for ``c`` in ``[-1, 1]``, within 1.5 units in the last place of the exact
    value (measured 1.13 ulp over 4e7 cosines: a grid of ``[-1, 1]`` and the ulps next to +-1,
    +-1/2 and 0; numpy's own ``arccos`` is within 0.82 ulp here) and so within 2 ulp of numpy's
    on any machine (1 ulp on this one), and branch-free so that loops over arrays of cosines
    vectorise (glibc's ``acos`` was a tenth of the online detectors' time, one call per angle).

    The classic reduction: ``arccos(c) = pi/2 - asin(c)`` for ``|c| <= 1/2``, else
    ``2 asin(s)`` (``c > 0``) or ``pi - 2 asin(s)`` (``c < 0``) with ``s = sqrt((1 - |c|) / 2)``;
    ``asin(s) = s + s z g(z)``, ``z = s^2 <= 1/4``, with ``g`` a degree-11 polynomial
    (:data:`ARCCOS_G`), ``sqrt`` split in two halves (Veltkamp) so that ``2 asin(s)`` keeps its
    last bits near ``c = 1``, and pi in two parts."""
    a = abs(c)
    big = a > 0.5
    z = 0.5 * (1.0 - a) if big else a * a
    s = np.sqrt(z) if big else a
    q = _G11
    q = q * z + _G10
    q = q * z + _G9
    q = q * z + _G8
    q = q * z + _G7
    q = q * z + _G6
    q = q * z + _G5
    q = q * z + _G4
    q = q * z + _G3
    q = q * z + _G2
    q = q * z + _G1
    q = q * z + _G0
    r = s * (z * q)
    if big:
        t = s * 134217729.0  # 2^27 + 1
        hi = t - (t - s)
        p = hi + ((z - hi * hi) / (s + hi + 1e-300) + r)  # asin(s), z - hi^2 exact
        return 2.0 * p if c > 0.0 else np.pi - (2.0 * p - _PI_LO)
    p = s + r
    return np.pi / 2 - (p - _PIO2_LO) if c >= 0.0 else np.pi / 2 + (p + _PIO2_LO)


@njit(cache=True, nogil=True, error_model="numpy")
def arccos_into(c, n):
    """``c[:n] = degrees(arccos(c[:n]))`` in place (:func:`arccos`; a loop that vectorises), within
    3 ulp of the exact degrees (measured 2.70 ulp: the radians' error times 180/pi plus the
    rounding of the conversion; 2 ulp of ``np.degrees(np.arccos(c))``)."""
    for k in range(n):
        c[k] = np.degrees(arccos(c[k]))


@njit(cache=True, nogil=True)
def _cos_of(dot, na, nb):
    """The cosine of the angle between two vectors from their dot product and norms, in
    ``[-1, 1]``; 1 (angle 0) when either is the zero vector."""
    if na == 0.0 or nb == 0.0:
        return 1.0
    return min(1.0, max(-1.0, dot / (na * nb)))


@njit(cache=True, nogil=True)
def _angle_deg(a, b):
    """The angle between ``a`` and ``b`` in degrees (0 when either is zero)."""
    na = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    nb = np.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    return np.degrees(arccos(_cos_of(a[0] * b[0] + a[1] * b[1] + a[2] * b[2], na, nb)))


@njit(cache=True, nogil=True)
def _norm(a0, a1, a2):
    return np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)


@njit(cache=True, nogil=True)
def _dist2(xyz, i, j):
    dx = xyz[i, 0] - xyz[j, 0]
    dy = xyz[i, 1] - xyz[j, 1]
    dz = xyz[i, 2] - xyz[j, 2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True)
def line_returns(line, valid):
    """Slot indices of the returns of one scan line, in line order (``line`` is ``-1``-padded;
    slots without a return, the paper's missing points M, are skipped)."""
    pts = np.empty(line.shape[0], np.int64)
    return pts[: line_returns_into(line, valid, pts)]


@njit(cache=True, nogil=True)
def line_returns_into(line, valid, pts):
    """:func:`line_returns` written into ``pts`` (at least the line's length); returns the count."""
    m = 0
    for j in range(line.shape[0]):
        s = line[j]
        if s < 0:
            break
        if valid[s]:
            pts[m] = s
            m += 1
    return m


@njit(cache=True, nogil=True)
def line_statistics(xyz, valid, line, origin, min_step=0.0, centred=False):
    """Signed angles ``sV`` and line angles ``phi_hat`` of one scan line (Sec. 3).

    ``D_k = X_{k+1} - X_k`` over the returns of the line in order; ``V_k`` is the angle of
    ``D_k`` with the z axis (0-180 deg); ``sV_k = s V_k`` with ``s`` the sign of
    ``D_k . D_{k-1}`` (+1 for the first). ``phi_k`` is the angle between ``D_k`` and the beam
    ``X_{k+1} - X_A``; on a straight line ``phi_{k+1} = phi_k - theta`` (the beam turns by
    theta), so ``phi_hat_k = phi_k + (sum of the beam angles from X_1 to X_{k+1})`` is
    constant along collinear points (the paper's ``phi_k + (k - 1) theta`` with the actual
    angles, which also covers missing points).

    ``min_step`` > 0 (beyond the paper) takes ``D_k`` to the first later return at least
    ``min_step`` away instead of the next one: on dense profiles whose point spacing is
    comparable to the range noise the paper's successive differences are noise. With
    ``centred``, ``D_k`` runs instead from the last earlier return at least ``min_step / 2``
    away to the first later one at least ``min_step / 2`` away, so that a step's steep angle
    lands on the step's own returns (a curb face) rather than on the returns before it.
    With ``min_step = 0`` this is the paper's definition. Values belong to point ``k`` (the
    last return repeats its predecessor's).

    Returns
    -------
    pts : int64 (m,)   slot indices of the returns, in line order
    sv, phi_hat : float64 (m,)
    """
    pts = np.empty(line.shape[0], np.int64)
    sv = np.empty(line.shape[0])
    phi_hat = np.empty(line.shape[0])
    work = np.empty((2, line.shape[0]))
    n = line_statistics_into(xyz, valid, line, origin, min_step, centred, pts, sv, phi_hat, work)
    return pts[:n], sv[:n], phi_hat[:n]


@njit(cache=True, nogil=True)
def line_statistics_into(xyz, valid, line, origin, min_step, centred, pts, sv, phi_hat, work):
    """:func:`line_statistics` written into ``pts, sv, phi_hat`` (each at least the line's
    length; ``work`` a float64 scratch of 2 such rows: no allocation, for callers that reuse one
    set of buffers for many lines); returns the number of returns ``n`` (the results are the
    first ``n`` entries)."""
    n = line_returns_into(line, valid, pts)
    statistics_of_returns(xyz, pts, n, origin, min_step, centred, sv, phi_hat, work)
    return n


@njit(cache=True, nogil=True)
def statistics_of_returns(xyz, pts, n, origin, min_step, centred, sv, phi_hat, work):
    """:func:`line_statistics` of the returns ``xyz[pts[0]], ..., xyz[pts[n - 1]]`` (a line's
    returns in order), written into ``sv[:n], phi_hat[:n]`` (``work``: float64 scratch, 2 rows
    of at least ``n``). Callers that hold the returns' coordinates in order pass them as ``xyz``
    with ``pts = 0, 1, ...``.

    Three passes: the cosines of every step's three angles (``V_k``, the beam's turn, ``phi_k``),
    then their arccos in loops that vectorise (:func:`arccos_into`), then the signs and the
    running sum of the beam's turns."""
    if n < 2:
        for k in range(n):
            sv[k] = 0.0
            phi_hat[k] = 0.0
        return
    turn, signs = work[0], work[1]
    p0 = p1 = p2 = 0.0  # D_{k-1}
    b0 = b1 = b2 = 0.0  # X_{k+1} - X_A
    n_ra = 0.0  # |X_k - X_A|: the previous step's |X_{k+1} - X_A|
    nxt = 1
    lo = 0
    turn[0] = 1.0  # no turn before the first step
    for k in range(n - 1):
        a = k
        step = min_step
        if centred and min_step > 0.0:  # D_k from >= min_step/2 before X_k to >= min_step/2 after
            step = 0.5 * min_step
            while lo + 1 < k and _dist2(xyz, pts[lo + 1], pts[k]) >= step * step:
                lo += 1
            a = lo
        nxt = max(nxt, k + 1)
        while step > 0.0 and nxt < n - 1 and _dist2(xyz, pts[nxt], pts[k]) < step * step:  # (none < 0)
            nxt += 1
        b = nxt
        ra0, ra1, ra2 = b0, b1, b2  # X_k - X_A: the previous step's (unused at k = 0)
        pb, pa, pk = pts[b], pts[a], pts[k + 1]
        d0, d1, d2 = xyz[pb, 0] - xyz[pa, 0], xyz[pb, 1] - xyz[pa, 1], xyz[pb, 2] - xyz[pa, 2]
        b0, b1, b2 = xyz[pk, 0] - origin[0], xyz[pk, 1] - origin[1], xyz[pk, 2] - origin[2]
        # the cosines of _angle_deg, each norm taken once (the same values, fewer square roots)
        n_d = _norm(d0, d1, d2)
        n_rb = _norm(b0, b1, b2)
        sv[k] = _cos_of(d0 * 0.0 + d1 * 0.0 + d2 * 1.0, n_d, 1.0)  # with the z axis
        signs[k] = -1.0 if k > 0 and (d0 * p0 + d1 * p1 + d2 * p2) < 0.0 else 1.0
        if k > 0:
            turn[k] = _cos_of(ra0 * b0 + ra1 * b1 + ra2 * b2, n_ra, n_rb)  # beam X_k -> X_{k+1}
        phi_hat[k] = _cos_of(d0 * b0 + d1 * b1 + d2 * b2, n_d, n_rb)
        n_ra = n_rb
        p0, p1, p2 = d0, d1, d2
    arccos_into(sv, n - 1)
    arccos_into(turn, n - 1)
    arccos_into(phi_hat, n - 1)
    cum = 0.0
    for k in range(n - 1):
        sv[k] *= signs[k]
        if k > 0:
            cum += turn[k]
        phi_hat[k] += cum
    sv[n - 1] = sv[n - 2]
    phi_hat[n - 1] = phi_hat[n - 2]


@njit(cache=True, nogil=True)
def hmm_cusum(x, means, sigma, a0, a1, h):
    """Online CUSUM between two hidden Markov models with Gaussian emissions (Sec. 4, 7.1).

    Both models are filtered forward; ``LLR_k = log p1(x_k | past) - log p0(x_k | past)``
    from their one-step predictive likelihoods. The detector switches between "regular"
    (H0) and "changed" (H1): in H0 it accumulates ``W = max(0, W + LLR)`` and on ``W > h``
    marks every sample since ``W`` last was 0 as changed; in H1 it runs the mirrored
    statistic with ``-LLR`` to detect the return.

    Returns
    -------
    changed : bool (n,)
    """
    if means.shape[0] == 3:
        return _hmm_cusum3(x, means, sigma, a0, a1, h)
    return _hmm_cusum_n(x, means, sigma, a0, a1, h)


@njit(cache=True, nogil=True, inline="always")
def _cusum_step(llr, k, state, w, start, h, changed):
    """One step of the CUSUM between the two chains at sample ``k``: ``llr`` is log l1 - log l0;
    past ``h`` the state switches and the samples since the statistic last left zero take the new
    state (marked in ``changed``). Returns ``(state, w, start)``."""
    if state == 1:
        llr = -llr
    w = max(0.0, w + llr)
    if w == 0.0:
        start = k + 1
    elif w > h:
        for j in range(start, k + 1):
            changed[j] = state == 0
        state = 1 - state
        w = 0.0
        start = k + 1
    if state == 1:
        changed[k] = True
    return state, w, start


@njit(cache=True, nogil=True)
def _hmm_cusum_n(x, means, sigma, a0, a1, h):
    """:func:`hmm_cusum` for any number of states."""
    n = x.shape[0]
    ns = means.shape[0]
    changed = np.zeros(n, np.bool_)
    f0 = np.full(ns, 1.0 / ns)
    f1 = np.full(ns, 1.0 / ns)
    p0 = np.empty(ns)
    p1 = np.empty(ns)
    norm = 1.0 / (sigma * np.sqrt(2 * np.pi))
    state = 0
    w = 0.0
    start = 0
    for k in range(n):
        l0 = 0.0
        l1 = 0.0
        for j in range(ns):
            r = (x[k] - means[j]) / sigma
            e = np.exp(-0.5 * r * r) * norm + 1e-300
            s0 = 0.0
            s1 = 0.0
            for i in range(ns):
                s0 += f0[i] * a0[i, j]
                s1 += f1[i] * a1[i, j]
            p0[j] = s0 * e
            p1[j] = s1 * e
            l0 += p0[j]
            l1 += p1[j]
        for j in range(ns):
            f0[j] = p0[j] / l0
            f1[j] = p1[j] / l1
        state, w, start = _cusum_step(np.log(l1) - np.log(l0), k, state, w, start, h, changed)
    return changed


@njit(cache=True, nogil=True)
def _hmm_cusum3(x, means, sigma, a0, a1, h):
    """:func:`hmm_cusum` with three states (the paper's -90 / 0 / 90 deg), the filter held in
    scalars (:func:`hmm_cusum3_into`)."""
    changed = np.empty(x.shape[0], np.bool_)
    hmm_cusum3_into(x, means, sigma, a0, a1, h, changed)
    return changed


@njit(cache=True, nogil=True)
def hmm_cusum3_into(x, means, sigma, a0, a1, h, changed):
    """:func:`_hmm_cusum3` written into ``changed[:len(x)]`` (no allocation).

    Means spaced evenly (``m0 = m1 - a``, ``m2 = m1 + a``, as the paper's -90 / 0 / 90 deg and
    T' -150 / 0 / 150 deg) take :func:`_hmm_cusum3_even_into`, one ``exp`` per sample; other
    means, or samples so far out that its factors would overflow, the plain filter."""
    a = means[1] - means[0]
    s = a / (sigma * sigma)
    far = 0.0
    for k in range(x.shape[0]):
        far = max(far, abs(x[k] - means[1]))
    if means[2] - means[1] == a and a > 0.0 and 0.5 * a * s < 600.0 and far * s < 600.0:
        _hmm_cusum3_even_into(x, means[1], a, sigma, a0, a1, h, changed)
    else:
        _hmm_cusum3_plain_into(x, means, sigma, a0, a1, h, changed)


@njit(cache=True, nogil=True)
def _hmm_cusum3_plain_into(x, means, sigma, a0, a1, h, changed):
    """The three-state filter of :func:`hmm_cusum` held in scalars: the same operations in the
    same order as :func:`_hmm_cusum_n`, so the same values bit for bit."""
    n = x.shape[0]
    for k in range(n):
        changed[k] = False
    f00 = f01 = f02 = 1.0 / 3
    f10 = f11 = f12 = 1.0 / 3
    m0, m1, m2 = means[0], means[1], means[2]
    a000, a001, a002 = a0[0, 0], a0[0, 1], a0[0, 2]
    a010, a011, a012 = a0[1, 0], a0[1, 1], a0[1, 2]
    a020, a021, a022 = a0[2, 0], a0[2, 1], a0[2, 2]
    a100, a101, a102 = a1[0, 0], a1[0, 1], a1[0, 2]
    a110, a111, a112 = a1[1, 0], a1[1, 1], a1[1, 2]
    a120, a121, a122 = a1[2, 0], a1[2, 1], a1[2, 2]
    norm = 1.0 / (sigma * np.sqrt(2 * np.pi))
    state = 0
    w = 0.0
    start = 0
    for k in range(n):
        r = (x[k] - m0) / sigma
        e0 = np.exp(-0.5 * r * r) * norm + 1e-300
        r = (x[k] - m1) / sigma
        e1 = np.exp(-0.5 * r * r) * norm + 1e-300
        r = (x[k] - m2) / sigma
        e2 = np.exp(-0.5 * r * r) * norm + 1e-300
        p00 = (((0.0 + f00 * a000) + f01 * a010) + f02 * a020) * e0
        p10 = (((0.0 + f10 * a100) + f11 * a110) + f12 * a120) * e0
        p01 = (((0.0 + f00 * a001) + f01 * a011) + f02 * a021) * e1
        p11 = (((0.0 + f10 * a101) + f11 * a111) + f12 * a121) * e1
        p02 = (((0.0 + f00 * a002) + f01 * a012) + f02 * a022) * e2
        p12 = (((0.0 + f10 * a102) + f11 * a112) + f12 * a122) * e2
        l0 = ((0.0 + p00) + p01) + p02
        l1 = ((0.0 + p10) + p11) + p12
        f00, f01, f02 = p00 / l0, p01 / l0, p02 / l0
        f10, f11, f12 = p10 / l1, p11 / l1, p12 / l1
        state, w, start = _cusum_step(np.log(l1) - np.log(l0), k, state, w, start, h, changed)


@njit(cache=True, nogil=True, inline="always")
def _cusum_step_ratio(ratio, k, state, big_w, start, big_h, changed):
    """:func:`_cusum_step` on the exponentials: ``ratio = l1 / l0 = exp(LLR)``, ``big_w = exp(W)``,
    ``big_h = exp(h)``; ``max(0, W + LLR)`` is ``max(1, big_w * ratio)``, and ``W > h`` is
    ``big_w > big_h`` (exp is monotone: the same decisions, up to rounding, without a log)."""
    if state == 1:
        ratio = 1.0 / ratio
    big_w = max(1.0, big_w * ratio)
    if big_w == 1.0:
        start = k + 1
    elif big_w > big_h:
        for j in range(start, k + 1):
            changed[j] = state == 0
        state = 1 - state
        big_w = 1.0
        start = k + 1
    if state == 1:
        changed[k] = True
    return state, big_w, start


@njit(cache=True, nogil=True)
def _hmm_cusum3_even_into(x, m1, a, sigma, a0, a1, h, changed):
    """:func:`hmm_cusum` for three states with means ``m1 - a, m1, m1 + a``, one ``exp`` per sample.

    Both forward filters are normalised at every step, and the LLR is the log of a ratio of
    their predictive likelihoods, so scaling the three emissions of a sample by one common
    factor changes neither. Dividing the Gaussians by the middle state's,
    ``e_j / e_1 = exp(-((x - m_j)^2 - (x - m_1)^2) / (2 sigma^2))``, leaves ``c / q``, 1 and
    ``c q`` with ``q = exp((x - m1) a / sigma^2)`` and ``c = exp(-a^2 / (2 sigma^2))``; the CUSUM
    runs on ``exp(LLR)`` (:func:`_cusum_step_ratio`). The caller keeps ``q`` and ``c`` in range."""
    n = x.shape[0]
    for k in range(n):
        changed[k] = False
    f00 = f01 = f02 = 1.0 / 3
    f10 = f11 = f12 = 1.0 / 3
    a000, a001, a002 = a0[0, 0], a0[0, 1], a0[0, 2]
    a010, a011, a012 = a0[1, 0], a0[1, 1], a0[1, 2]
    a020, a021, a022 = a0[2, 0], a0[2, 1], a0[2, 2]
    a100, a101, a102 = a1[0, 0], a1[0, 1], a1[0, 2]
    a110, a111, a112 = a1[1, 0], a1[1, 1], a1[1, 2]
    a120, a121, a122 = a1[2, 0], a1[2, 1], a1[2, 2]
    s = a / (sigma * sigma)
    c = np.exp(-0.5 * a * s)
    big_h = np.exp(h)
    state = 0
    big_w = 1.0
    start = 0
    for k in range(n):
        q = np.exp((x[k] - m1) * s)
        e0 = c / q
        e2 = c * q
        p00 = (f00 * a000 + f01 * a010 + f02 * a020) * e0
        p10 = (f10 * a100 + f11 * a110 + f12 * a120) * e0
        p01 = f00 * a001 + f01 * a011 + f02 * a021
        p11 = f10 * a101 + f11 * a111 + f12 * a121
        p02 = (f00 * a002 + f01 * a012 + f02 * a022) * e2
        p12 = (f10 * a102 + f11 * a112 + f12 * a122) * e2
        i0 = 1.0 / (p00 + p01 + p02)
        i1 = 1.0 / (p10 + p11 + p12)
        f00, f01, f02 = p00 * i0, p01 * i0, p02 * i0
        f10, f11, f12 = p10 * i1, p11 * i1, p12 * i1
        state, big_w, start = _cusum_step_ratio(i0 / i1, k, state, big_w, start, big_h, changed)


@njit(cache=True, nogil=True)
def mean_shift_cusum(x, mu_a, mu_b, sigma, h):
    """Two-state online CUSUM for a change of the mean between ``mu_a`` and ``mu_b`` (Sec. 4:
    horizontal vs vertical, a 90 deg change of the signed angle). Starts in the state whose
    mean is nearer the first sample; on an alarm the samples since the statistic was last 0
    take the new state.

    Returns
    -------
    in_b : bool (n,)
    """
    out = np.empty(x.shape[0], np.bool_)
    mean_shift_cusum_into(x, mu_a, mu_b, sigma, h, out)
    return out


@njit(cache=True, nogil=True)
def mean_shift_cusum_into(x, mu_a, mu_b, sigma, h, out):
    """:func:`mean_shift_cusum` written into ``out[:len(x)]`` (no allocation)."""
    n = x.shape[0]
    for k in range(n):
        out[k] = False
    if n == 0:
        return
    state = 1 if abs(x[0] - mu_b) < abs(x[0] - mu_a) else 0
    w = 0.0
    start = 0
    inv = 1.0 / (2.0 * sigma * sigma)
    for k in range(n):
        cur = mu_b if state == 1 else mu_a
        new = mu_a if state == 1 else mu_b
        llr = ((x[k] - cur) ** 2 - (x[k] - new) ** 2) * inv
        w = max(0.0, w + llr)
        if w == 0.0:
            start = k + 1
        elif w > h:
            state = 1 - state
            for j in range(start, k):
                out[j] = state == 1
            w = 0.0
            start = k + 1
        out[k] = state == 1


@njit(cache=True, nogil=True)
def relabel(seg, lut):
    """``lut[seg]`` for an image of ids (what numpy's indexing gives, without converting every
    id to a pointer-sized index first)."""
    out = np.empty(seg.shape, lut.dtype)
    flat, src = out.reshape(-1), seg.reshape(-1)
    for i in range(src.shape[0]):
        flat[i] = lut[src[i]]
    return out
