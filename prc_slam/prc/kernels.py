"""Numba kernels for the per-pixel steps of PRC (Lehtola et al. 2019, Algorithm 1).

Each kernel is one pass over a ``k x M`` block; the Python-level orchestration lives in
:mod:`prc_slam.prc.algorithm`. Row index = scan line ``l``, column index = position ``h``
in the scan line, so the paper's ``r_{i±1}`` are column neighbours and ``r_{i±M}`` row
neighbours.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from prc_slam.util import unionfind as uf


@njit(cache=True, nogil=True)
def support_counts(ranges, xi_s, xi_p, half_in, wrap, reach=0):
    """Support counts of eqs. (5)-(8) (reference kernel: the pipeline uses the one-pass
    :func:`support_and_gradient`, which tests check against this one).

    ``C_adj`` counts neighbours ``j`` in N_adj-slice (eq. 7: columns ``h-1, h, h+1`` of the
    previous and next scan line) with ``|r_i - r_j| < xi_s``; ``C_in`` counts neighbours in
    N_in-slice with ``|r_i - r_j| < xi_p``. Slots without a return (range 0) neither get nor
    give support. Per-slot thresholds are compared against ``max(xi_i, xi_j)`` so that
    ``delta_ij`` stays symmetric; with scalar-valued arrays this is the paper's fixed threshold.

    N_in-slice (eq. 8) is ``h-half_in .. h+half_in`` without ``h`` when ``reach <= half_in``
    (the paper's slots). With ``reach > half_in`` it is the eight closest range *measurements*
    of the scan line as the paper's text words it: on each side the ``half_in`` nearest
    returns within ``reach`` columns, skipping slots without a return (dropouts on dark or
    grazing surfaces otherwise leave real returns without the support they have).

    Returns
    -------
    c_adj, c_in : int8 arrays, shape (rows, cols)
    """
    R, C = ranges.shape
    c_adj = np.zeros((R, C), np.int8)
    c_in = np.zeros((R, C), np.int8)
    span = max(reach, half_in)
    for r in range(R):
        for c in range(C):
            ri = ranges[r, c]
            if ri <= 0.0:
                continue
            xs = xi_s[r, c]
            xp = xi_p[r, c]
            n_in = 0
            for sgn in (-1, 1):
                got = 0
                for d in range(1, span + 1):
                    if got == half_in:
                        break
                    cc = c + sgn * d
                    if cc < 0 or cc >= C:
                        if not wrap:
                            break
                        cc = cc % C
                    rj = ranges[r, cc]
                    if rj > 0.0:
                        if span > half_in:
                            got += 1
                        if abs(ri - rj) < max(xp, xi_p[r, cc]):
                            n_in += 1
            n_adj = 0
            for dr in (-1, 1):
                rr = r + dr
                if rr < 0 or rr >= R:
                    continue
                for d in (-1, 0, 1):
                    cc = c + d
                    if cc < 0 or cc >= C:
                        if not wrap:
                            continue
                        cc = cc % C
                    rj = ranges[rr, cc]
                    if rj > 0.0 and abs(ri - rj) < max(xs, xi_s[rr, cc]):
                        n_adj += 1
            c_adj[r, c] = n_adj
            c_in[r, c] = n_in
    return c_adj, c_in


@njit(cache=True, nogil=True)
def spinning_thresholds(ranges, xi_s, xi_p, row_step, col_step, factor, adaptive, factor2, second):
    """The support thresholds of a spinning sensor's block and, with ``second``, those of the
    one-sided rule, in one pass (float32, the same values as ``support_thresholds`` gives
    from ``SpinningSensor.neighbour_spacing``): ``max(xi_s, factor * (r * row_step[row]))``
    and ``max(xi_p, factor * (r * col_step))``, the constants alone without ``adaptive``;
    ``factor2`` for the one-sided rule's pair (the first pair again without ``second``).

    Returns
    -------
    xi_s, xi_p, xi_s2, xi_p2 : float32 arrays, shape (rows, cols)
    """
    R, C = ranges.shape
    out_s = np.empty((R, C), np.float32)
    out_p = np.empty((R, C), np.float32)
    out_s2 = np.empty((R, C), np.float32) if second else out_s
    out_p2 = np.empty((R, C), np.float32) if second else out_p
    for r in range(R):
        rs = row_step[r]
        rr = ranges[r]
        a_s = out_s[r]
        a_p = out_p[r]
        b_s = out_s2[r]
        b_p = out_p2[r]
        for c in range(C):
            s_adj = rr[c] * rs
            s_in = rr[c] * col_step
            if adaptive:
                v = factor * s_adj
                a_s[c] = xi_s if xi_s >= v else v
                v = factor * s_in
                a_p[c] = xi_p if xi_p >= v else v
            else:
                a_s[c] = xi_s
                a_p[c] = xi_p
            if second:
                v = factor2 * s_adj
                b_s[c] = xi_s if xi_s >= v else v
                v = factor2 * s_in
                b_p[c] = xi_p if xi_p >= v else v
    return out_s, out_p, out_s2, out_p2


@njit(cache=True, nogil=True, inline="always")
def _support_met(ranges, r, c, xi_s, xi_p, half_in, need_in, need_adj, wrap, uniform, reach):
    """Whether return ``(r, c)`` meets the in-slice and the adjacent-slice condition of eq. (4)
    (see :func:`support_counts` for the neighbourhoods); counting stops as soon as each
    outcome is decided, nearest neighbours first."""
    R, C = ranges.shape
    ri = ranges[r, c]
    xs = xi_s[r, c]
    xp = xi_p[r, c]
    n_in = 0
    if reach <= half_in:
        interior = c - half_in >= 0 and c + half_in < C
        left = 2 * half_in
        for k in range(1, half_in + 1):
            for sgn in (-1, 1):
                cc = c + sgn * k
                left -= 1
                if not interior and (cc < 0 or cc >= C):
                    if not wrap:
                        continue
                    cc = cc % C
                rj = ranges[r, cc]
                if rj > 0.0 and abs(ri - rj) < (xp if uniform else max(xp, xi_p[r, cc])):
                    n_in += 1
            if n_in >= need_in or n_in + left < need_in:
                break
    else:
        got_l = 0
        got_r = 0
        for k in range(1, reach + 1):
            for sgn in (-1, 1):
                if (got_l if sgn < 0 else got_r) >= half_in:
                    continue
                cc = c + sgn * k
                if cc < 0 or cc >= C:
                    if not wrap:
                        if sgn < 0:
                            got_l = half_in
                        else:
                            got_r = half_in
                        continue
                    cc = cc % C
                rj = ranges[r, cc]
                if rj > 0.0:
                    if sgn < 0:
                        got_l += 1
                    else:
                        got_r += 1
                    if abs(ri - rj) < (xp if uniform else max(xp, xi_p[r, cc])):
                        n_in += 1
            if n_in >= need_in or n_in + 2 * half_in - got_l - got_r < need_in:
                break
            if got_l >= half_in and got_r >= half_in:
                break
    in_ok = n_in >= need_in
    n_adj = 0
    for d in (0, -1, 1):
        cc = c + d
        if cc < 0 or cc >= C:
            if not wrap:
                continue
            cc = cc % C
        if r > 0:
            rj = ranges[r - 1, cc]
            if rj > 0.0 and abs(ri - rj) < (xs if uniform else max(xs, xi_s[r - 1, cc])):
                n_adj += 1
        if r + 1 < R:
            rj = ranges[r + 1, cc]
            if rj > 0.0 and abs(ri - rj) < (xs if uniform else max(xs, xi_s[r + 1, cc])):
                n_adj += 1
        if n_adj >= need_adj:
            break
    return in_ok, n_adj >= need_adj


@njit(cache=True, nogil=True)
def _padded(ranges, xi_s, wrap):
    """Copies of ``ranges`` and ``xi_s`` with one column of padding each side (the other end
    of the row when ``wrap``, else empty) and one row of empty slots above and below."""
    R, C = ranges.shape
    pr = np.zeros((R + 2, C + 2), np.float32)
    pt = np.zeros((R + 2, C + 2), np.float32)
    for r in range(R):
        for c in range(C):
            pr[r + 1, c + 1] = ranges[r, c]
            pt[r + 1, c + 1] = xi_s[r, c]
        if wrap:
            pr[r + 1, 0] = ranges[r, C - 1]
            pt[r + 1, 0] = xi_s[r, C - 1]
            pr[r + 1, C + 1] = ranges[r, 0]
            pt[r + 1, C + 1] = xi_s[r, 0]
    return pr, pt


@njit(cache=True, nogil=True)
def _support_rows(ranges, pr, pt, xi_p, half_in, need_in, need_adj, wrap, uniform, reach, r0, r1):
    """The two conditions of eq. (4) for every slot, counted row by row without branches (the
    loops vectorise): the same neighbourhoods as :func:`support_counts`, for images with more
    than ``2 max(reach, half_in) + 1`` columns (no slot is then its own or a double neighbour).

    In-slice (eq. 8): each row's returns are packed (column, range, threshold), padded by
    ``half_in`` entries on each side (the other end of the row when ``wrap``, else entries too
    far to count); the neighbours of a return are the ``half_in`` packed entries on each side
    within ``max(reach, half_in)`` columns, which are the paper's slots when ``reach <=
    half_in`` and the closest returns otherwise. Adjacent slice (eq. 7): columns ``c-1..c+1``
    of the rows above and below, read from the padded copies ``pr, pt`` of ``ranges, xi_s``
    (:func:`_padded`).

    Returns
    -------
    in_met, adj_met : bool arrays, shape (r1 - r0, cols): rows ``r0..r1-1``, False for slots
        without a return
    """
    C = ranges.shape[1]
    h = half_in
    span = max(reach, half_in)
    far = 4 * C + 4 * span + 4
    in_met_all = np.zeros((r1 - r0, C), np.bool_)
    adj_met_all = np.zeros((r1 - r0, C), np.bool_)
    pos = np.empty(C + 2 * h, np.int64)
    val = np.empty(C + 2 * h, np.float32)
    thr = np.empty(C + 2 * h, np.float32)
    idx = np.empty(C, np.int64)
    cnt = np.zeros(C, np.int32)
    for r in range(r0, r1):
        in_met = in_met_all[r - r0]
        adj_met = adj_met_all[r - r0]
        # ---- in-slice (eq. 8): pack the row's returns, pad, count over shifted views
        m = 0
        for c in range(C):
            if ranges[r, c] > 0.0:
                idx[m] = c
                m += 1
        if m == 0:
            continue
        for k in range(m):
            c = idx[k]
            pos[h + k] = c
            val[h + k] = ranges[r, c]
            thr[h + k] = xi_p[r, c]
        for t in range(h):  # entries -h..-1 and m..m+h-1
            if wrap:
                src = (t - h) % m
                pos[t] = idx[src] + (t - h - src) // m * C
                val[t] = ranges[r, idx[src]]
                thr[t] = xi_p[r, idx[src]]
                src = (m + t) % m
                pos[h + m + t] = idx[src] + (m + t - src) // m * C
                val[h + m + t] = ranges[r, idx[src]]
                thr[h + m + t] = xi_p[r, idx[src]]
            else:
                pos[t] = -far
                val[t] = 0.0
                thr[t] = 0.0
                pos[h + m + t] = far
                val[h + m + t] = 0.0
                thr[h + m + t] = 0.0
        n = cnt[:m]
        n[:] = 0
        p0 = pos[h : h + m]
        v0 = val[h : h + m]
        t0 = thr[h : h + m]
        for j in range(1, h + 1):
            pa = pos[h + j : h + j + m]
            va = val[h + j : h + j + m]
            ta = thr[h + j : h + j + m]
            pb = pos[h - j : h - j + m]
            vb = val[h - j : h - j + m]
            tb = thr[h - j : h - j + m]
            if uniform:
                for k in range(m):
                    n[k] += np.int32(pa[k] - p0[k] <= span) * np.int32(abs(v0[k] - va[k]) < t0[k]) + np.int32(
                        p0[k] - pb[k] <= span
                    ) * np.int32(abs(v0[k] - vb[k]) < t0[k])
            else:
                for k in range(m):
                    n[k] += np.int32(pa[k] - p0[k] <= span) * np.int32(
                        abs(v0[k] - va[k]) < max(t0[k], ta[k])
                    ) + np.int32(p0[k] - pb[k] <= span) * np.int32(abs(v0[k] - vb[k]) < max(t0[k], tb[k]))
        for k in range(m):
            in_met[idx[k]] = n[k] >= need_in
        # ---- adjacent slice (eq. 7): columns c-1, c, c+1 of the rows above and below
        n = cnt[:C]
        n[:] = 0
        v0 = pr[r + 1, 1 : C + 1]
        t0 = pt[r + 1, 1 : C + 1]
        for q in (r, r + 2):
            for d in range(3):
                va = pr[q, d : d + C]
                ta = pt[q, d : d + C]
                if uniform:
                    for c in range(C):
                        n[c] += np.int32(va[c] > 0.0) * np.int32(abs(v0[c] - va[c]) < t0[c])
                else:
                    for c in range(C):
                        n[c] += np.int32(va[c] > 0.0) * np.int32(abs(v0[c] - va[c]) < max(t0[c], ta[c]))
        for c in range(C):
            adj_met[c] = (n[c] >= need_adj) & (v0[c] > 0.0)
    return in_met_all, adj_met_all


@njit(cache=True, nogil=True)
def support_and_gradient(
    ranges,
    xi_s,
    xi_p,
    half_in,
    need_in,
    need_adj,
    alpha,
    d_c,
    literal,
    wrap,
    both_axes,
    uniform,
    reach,
    xi_s2,
    xi_p2,
    second,
):
    """``S_b`` of eq. (2) and ``G_b`` of eq. (9) in one pass over the block.

    A return is supported when it meets both conditions of eq. (4) (eqs. 5-8, neighbourhoods
    and ``reach`` as in :func:`support_counts`, whose result this equals). Supported points
    are then tested by eq. (9) as in :func:`gradient_background`. ``uniform`` says the
    threshold arrays are constant, which spares the neighbours' threshold loads.

    Returns
    -------
    supported, grad : bool arrays, shape (rows, cols)
    one_sided : bool array, shape (rows, cols)
        Unsupported returns (noise) that are not isolated. Without ``second``: those that meet
        exactly one of the two conditions of eq. (4) (thin poles meet the adjacent-slice one
        only). With ``second`` (our *one-sided rule*, beyond the paper): a second pass over the
        unsupported returns only, asking for either condition under the stricter thresholds
        ``xi_s2, xi_p2`` (ignored without ``second``), so that an outlier that met one
        condition by chance under lenient thresholds is not spared.
    """
    R, C = ranges.shape
    sup = np.zeros((R, C), np.bool_)
    grad = np.zeros((R, C), np.bool_)
    one_sided = np.zeros((R, C), np.bool_)
    if C > 2 * max(reach, half_in) + 1:
        # row-wise counting (vectorised); every neighbourhood fits in a row without overlap
        pr, pt = _padded(ranges, xi_s, wrap)
        support_rows(
            ranges, pr, pt, xi_s, xi_p, half_in, need_in, need_adj, alpha, d_c, literal, wrap, both_axes, uniform,
            reach, xi_s2, xi_p2, second, sup, grad, one_sided, 0, R,
        )  # fmt: skip
        return sup, grad, one_sided
    for r in range(R):
        for c in range(C):
            ri = ranges[r, c]
            if ri <= 0.0:
                continue
            in_ok, adj_ok = _support_met(ranges, r, c, xi_s, xi_p, half_in, need_in, need_adj, wrap, uniform, reach)
            if not in_ok or not adj_ok:
                if second:
                    in2, adj2 = _support_met(ranges, r, c, xi_s2, xi_p2, half_in, need_in, need_adj, wrap, False, reach)
                    one_sided[r, c] = in2 or adj2
                else:
                    one_sided[r, c] = in_ok or adj_ok
                continue
            sup[r, c] = True
            cm = c - 1
            cp = c + 1
            if cm < 0 or cp >= C:
                if wrap:
                    cm = cm % C
                    cp = cp % C
                else:
                    cm = -1
            if cm >= 0 and _gradient_break(ranges[r, cm], ri, ranges[r, cp], alpha, d_c, literal):
                grad[r, c] = True
            elif both_axes and r > 0 and r + 1 < R:
                grad[r, c] = _gradient_break(ranges[r - 1, c], ri, ranges[r + 1, c], alpha, d_c, literal)
    return sup, grad, one_sided


@njit(cache=True, nogil=True)
def support_rows(
    ranges,
    pr,
    pt,
    xi_s,
    xi_p,
    half_in,
    need_in,
    need_adj,
    alpha,
    d_c,
    literal,
    wrap,
    both_axes,
    uniform,
    reach,
    xi_s2,
    xi_p2,
    second,
    sup,
    grad,
    one_sided,
    r0,
    r1,
):
    """Rows ``r0..r1-1`` of :func:`support_and_gradient` for blocks of more than
    ``2 max(reach, half_in) + 1`` columns, written into ``sup, grad, one_sided`` (rows outside
    are neither read nor written: row ranges can be run on separate threads). ``pr, pt``:
    :func:`_padded` of ``ranges, xi_s``."""
    C = ranges.shape[1]
    in_met, adj_met = _support_rows(ranges, pr, pt, xi_p, half_in, need_in, need_adj, wrap, uniform, reach, r0, r1)
    for r in range(r0, r1):
        v0 = pr[r + 1, 1 : C + 1]
        left = pr[r + 1, 0:C]
        right = pr[r + 1, 2 : C + 2]
        up = pr[r, 1 : C + 1]
        down = pr[r + 2, 1 : C + 1]
        im = in_met[r - r0]
        am = adj_met[r - r0]
        for c in range(C):
            s_ok = im[c] & am[c]
            sup[r, c] = s_ok
            g = _gradient_break(left[c], v0[c], right[c], alpha, d_c, literal)
            if both_axes:
                g = g | _gradient_break(up[c], v0[c], down[c], alpha, d_c, literal)
            grad[r, c] = s_ok & g
        for c in range(C):
            if v0[c] > 0.0 and not sup[r, c]:
                if second:
                    in2, adj2 = _support_met(ranges, r, c, xi_s2, xi_p2, half_in, need_in, need_adj, wrap, False, reach)
                    one_sided[r, c] = in2 or adj2
                else:
                    one_sided[r, c] = im[c] or am[c]


@njit(cache=True, nogil=True)
def gradient_background(ranges, supported, alpha, d_c, literal, wrap, both_axes):
    """Extension of the background by eq. (9): the set G_b of supported points (reference
    kernel; the pipeline computes it inside :func:`support_and_gradient`).

    Eq. (9) keeps point ``i`` in the foreground while
    ``alpha < (r_i - r_{i-1}) / max(r_{i+1} - r_{i-1}, d_c) < 1 - alpha``.
    With ``literal`` the inequality is evaluated as printed. Otherwise the symmetric form
    ``|(r_{i+1} - r_i) - (r_i - r_{i-1})| < (1 - 2 alpha) max(|r_{i+1} - r_{i-1}|, d_c)``
    is used: identical to eq. (9) whenever ``r_{i+1} - r_{i-1} >= d_c`` (the two are the same
    inequality, ``|a/(a+b) - 1/2| < 1/2 - alpha``), but it also keeps smooth surfaces whose
    range falls or stays constant along the scan line, which the printed form would send to
    the background wholesale. Points whose in-slice neighbours have no return are not
    evaluated (they stay foreground).

    With ``both_axes`` the same test is also applied across scan lines (rows ``l-1, l, l+1``
    of one column), where a spinning sensor's ground-to-wall crease lies.
    """
    R, C = ranges.shape
    g = np.zeros((R, C), np.bool_)
    for r in range(R):
        for c in range(C):
            if not supported[r, c]:
                continue
            ri = ranges[r, c]
            cm = c - 1
            cp = c + 1
            if cm >= 0 and cp < C:
                if _gradient_break(ranges[r, cm], ri, ranges[r, cp], alpha, d_c, literal):
                    g[r, c] = True
                    continue
            elif wrap:
                if _gradient_break(ranges[r, cm % C], ri, ranges[r, cp % C], alpha, d_c, literal):
                    g[r, c] = True
                    continue
            if both_axes and r > 0 and r + 1 < R:
                if _gradient_break(ranges[r - 1, c], ri, ranges[r + 1, c], alpha, d_c, literal):
                    g[r, c] = True
    return g


@njit(cache=True, nogil=True, inline="always")
def _gradient_break(a, ri, b, alpha, d_c, literal):
    """True when eq. (9) fails for ``r_{i-1} = a, r_i = ri, r_{i+1} = b`` (False if a neighbour
    has no return)."""
    # without branches (the callers' loops vectorise)
    both = (a > 0.0) & (b > 0.0)
    if literal:
        q = (ri - a) / max(b - a, d_c)
        return both & (not ((alpha < q) & (q < 1.0 - alpha)))
    return both & (abs((b - ri) - (ri - a)) >= (1.0 - 2.0 * alpha) * max(abs(b - a), d_c))


@njit(cache=True, nogil=True)
def connected_components(mask, wrap):
    """4-connected components of a binary image (Section II-D), by union-find over the runs
    of each row: a run joins the runs of the row above that share a column with it.

    Labels are ``1..n`` in raster order of each component's first pixel; background is 0.
    With ``wrap`` the first and last columns are neighbours (a full sensor revolution).
    Equal to :func:`connected_components_within` with ``max_dist = inf`` (the pixel-wise
    form, which tests compare it with).

    Returns
    -------
    labels : int32 array, shape (rows, cols)
    n : int
    """
    R, C = mask.shape
    cap = R * (C // 2 + 1) + 1  # runs per row <= ceil(C / 2); one spare for the branch-free writes
    start = np.empty(cap, np.int32)
    end = np.empty(cap, np.int32)
    first = np.empty(R + 1, np.int64)
    nr = 0
    for r in range(R):
        first[r] = nr
        row = mask[r]
        c = 0
        while c < C:  # runs are long: skipping over them beats a branch-free pass per pixel
            if not row[c]:
                c += 1
                continue
            start[nr] = c
            while c < C and row[c]:
                c += 1
            end[nr] = c
            nr += 1
    first[R] = nr
    parent = np.arange(nr).astype(np.int32)
    for r in range(1, R):
        i, i_end = first[r], first[r + 1]
        j, j_end = first[r - 1], first[r]
        while i < i_end and j < j_end:
            if end[j] <= start[i]:
                j += 1
            elif end[i] <= start[j]:
                i += 1
            else:
                uf.union(parent, i, j)
                if end[j] < end[i]:
                    j += 1
                else:
                    i += 1
    if wrap and C > 1:
        for r in range(R):
            a, b = first[r], first[r + 1]
            if b > a and start[a] == 0 and end[b - 1] == C:
                uf.union(parent, a, b - 1)
    final = np.zeros(nr, np.int32)
    lab = np.zeros((R, C), np.int32)
    k = 0
    for r in range(R):
        for q in range(first[r], first[r + 1]):
            root = uf.find(parent, q)
            if final[root] == 0:
                k += 1
                final[root] = k
            v = final[root]
            for c in range(start[q], end[q]):
                lab[r, c] = v
    return lab, k


@njit(cache=True, nogil=True)
def _near(xyz, r0, c0, r1, c1, max_dist):
    if max_dist == np.inf:
        return True
    d = 0.0
    for k in range(3):
        d += (xyz[r0, c0, k] - xyz[r1, c1, k]) ** 2
    return d <= max_dist * max_dist


@njit(cache=True, nogil=True)
def connected_components_within(mask, xyz, max_dist, wrap):
    """``connected_components`` where 4-neighbours join only when their points (``xyz``, shape
    (rows, cols, 3)) lie at most ``max_dist`` apart; ``max_dist = inf`` ignores ``xyz``."""
    R, C = mask.shape
    lab = np.zeros((R, C), np.int32)
    parent = np.zeros(R * C + 2, np.int32) if max_dist != np.inf else np.zeros(R * C // 2 + 2 + R, np.int32)
    n = 0
    for r in range(R):
        for c in range(C):
            if not mask[r, c]:
                continue
            up = lab[r - 1, c] if r > 0 and _near(xyz, r, c, r - 1, c, max_dist) else 0
            left = lab[r, c - 1] if c > 0 and _near(xyz, r, c, r, c - 1, max_dist) else 0
            if up == 0 and left == 0:
                n += 1
                parent[n] = n
                lab[r, c] = n
            elif up != 0 and left != 0:
                lab[r, c] = min(up, left)
                if up != left:
                    uf.union(parent, up, left)
            else:
                lab[r, c] = up if up != 0 else left
    if wrap and C > 1:
        for r in range(R):
            if lab[r, 0] != 0 and lab[r, C - 1] != 0 and _near(xyz, r, 0, r, C - 1, max_dist):
                uf.union(parent, lab[r, 0], lab[r, C - 1])
    final = np.zeros(n + 1, np.int32)
    k = 0
    for r in range(R):
        for c in range(C):
            v = lab[r, c]
            if v == 0:
                continue
            root = uf.find(parent, v)
            if final[root] == 0:
                k += 1
                final[root] = k
            lab[r, c] = final[root]
    return lab, k


@njit(cache=True, nogil=True)
def fill_holes(labels, holes, wrap):
    """Hole filling of Section II-D-1: each hole pixel takes the nonzero label most common in
    its 8-neighbourhood of ``labels`` (ties: the smaller label); 0 when it has none.

    ``labels`` is not modified; the neighbourhoods are read from it, so the result does not
    depend on the order in which holes are visited.
    """
    R, C = labels.shape
    # padded copy: neighbour reads need no bounds checks
    pad = np.zeros((R + 2, C + 2), np.int32)
    pad[1:-1, 1:-1] = labels
    if wrap:
        pad[1:-1, 0] = labels[:, C - 1]
        pad[1:-1, C + 1] = labels[:, 0]
    out = labels.copy()
    v = np.zeros(8, np.int32)
    for r in range(R):
        for c in range(C):
            if not holes[r, c]:
                continue
            v[0] = pad[r, c]
            v[1] = pad[r, c + 1]
            v[2] = pad[r, c + 2]
            v[3] = pad[r + 1, c]
            v[4] = pad[r + 1, c + 2]
            v[5] = pad[r + 2, c]
            v[6] = pad[r + 2, c + 1]
            v[7] = pad[r + 2, c + 2]
            # common case: every labelled neighbour carries the same label
            first = 0
            mixed = False
            for a in range(8):
                if v[a] != 0:
                    if first == 0:
                        first = v[a]
                    elif v[a] != first:
                        mixed = True
            if not mixed:
                out[r, c] = first
                continue
            best = 0
            best_n = 0
            for a in range(8):
                va = v[a]
                if va == 0:
                    continue
                n = 0
                for b in range(8):
                    n += v[b] == va
                if n > best_n or (n == best_n and va < best):
                    best = va
                    best_n = n
            out[r, c] = best
    return out


@njit(cache=True, nogil=True)
def fill_holes_sized(labels, holes, wrap, n):
    """:func:`fill_holes` (same result) and the size of every label ``0..n`` after filling, in
    one pass; neighbourhoods are read with bounds checks for the hole pixels only (no padded
    copy).

    Returns
    -------
    out : int32 (rows, cols)
    size : int64 (n + 1,)
    """
    R, C = labels.shape
    out = np.empty((R, C), np.int32)
    size = np.zeros(n + 1, np.int64)
    v = np.zeros(8, np.int32)
    last = 0  # sizes counted by runs of one label (increments of one entry do not chain)
    run = 0
    for r in range(R):
        for c in range(C):
            if not holes[r, c]:
                x = labels[r, c]
                out[r, c] = x
                if x == last:
                    run += 1
                else:
                    size[last] += run
                    last = x
                    run = 1
                continue
            if 0 < r < R - 1 and 0 < c < C - 1:  # interior: no bounds to check
                v[0] = labels[r - 1, c - 1]
                v[1] = labels[r - 1, c]
                v[2] = labels[r - 1, c + 1]
                v[3] = labels[r, c - 1]
                v[4] = labels[r, c + 1]
                v[5] = labels[r + 1, c - 1]
                v[6] = labels[r + 1, c]
                v[7] = labels[r + 1, c + 1]
            else:
                cm = c - 1
                cp = c + 1
                if wrap:
                    if cm < 0:
                        cm += C
                    if cp >= C:
                        cp -= C
                a = 0
                for dr in range(-1, 2):
                    rr = r + dr
                    for dc in range(-1, 2):
                        if dr == 0 and dc == 0:
                            continue
                        cc = cm if dc < 0 else (cp if dc > 0 else c)
                        if rr < 0 or rr >= R or cc < 0 or cc >= C:
                            v[a] = 0
                        else:
                            v[a] = labels[rr, cc]
                        a += 1
            first = 0
            mixed = False
            for a in range(8):
                if v[a] != 0:
                    if first == 0:
                        first = v[a]
                    elif v[a] != first:
                        mixed = True
            best = first
            if mixed:
                best = 0
                best_n = 0
                for a in range(8):
                    va = v[a]
                    if va == 0:
                        continue
                    k = 0
                    for b in range(8):
                        k += v[b] == va
                    if k > best_n or (k == best_n and va < best):
                        best = va
                        best_n = k
            out[r, c] = best
            if best == last:
                run += 1
            else:
                size[last] += run
                last = best
                run = 1
    size[last] += run
    return out, size


@njit(cache=True, nogil=True)
def dilate4(mask, iterations, wrap):
    """Binary dilation with the 4-neighbourhood, ``iterations`` times (Section II-E)."""
    R, C = mask.shape
    cur = mask.copy()
    pad = np.zeros((R + 2, C + 2), np.bool_)
    for _ in range(iterations):
        pad[1:-1, 1:-1] = cur
        if wrap:
            pad[1:-1, 0] = cur[:, C - 1]
            pad[1:-1, C + 1] = cur[:, 0]
        for r in range(R):
            for c in range(C):
                cur[r, c] = pad[r + 1, c + 1] | pad[r, c + 1] | pad[r + 2, c + 1] | pad[r + 1, c] | pad[r + 1, c + 2]
    return cur


@njit(cache=True, nogil=True)
def split_smooth(h_local, smooth_lut):
    """Masks of the smooth (``H_b`` segments of at least A pixels) and small (``Ṽ_b`` of
    eq. 11) points, from block-local segment ids and a per-id smoothness table."""
    R, C = h_local.shape
    smooth = np.zeros((R, C), np.bool_)
    small = np.zeros((R, C), np.bool_)
    for r in range(R):
        for c in range(C):
            s = h_local[r, c]
            if s == 0:
                continue
            if smooth_lut[s]:
                smooth[r, c] = True
            else:
                small[r, c] = True
    return smooth, small


@njit(cache=True, nogil=True)
def combine(h_local, glob, smooth, small, dilated, v_local, v_offset, supported):
    """``R_b`` of step 5 (Sec. II-E): points of small segments, and supported points left
    unlabelled by hole filling that the dilation reached, take their ``V_b`` id; the other
    supported points keep their ``H_b`` id; unsupported points get 0.

    Returns
    -------
    segments : int32 (rows, cols)
    nonsmooth : bool (rows, cols)
    """
    R, C = h_local.shape
    seg = np.zeros((R, C), np.int32)
    nonsmooth = np.zeros((R, C), np.bool_)
    for r in range(R):
        for c in range(C):
            if not supported[r, c]:
                continue
            s = h_local[r, c]
            if small[r, c] or (s == 0 and dilated[r, c]):
                nonsmooth[r, c] = True
                v = v_local[r, c]
                seg[r, c] = v + v_offset if v > 0 else 0
            else:
                seg[r, c] = glob[s]
    return seg, nonsmooth


@njit(cache=True, nogil=True)
def combine_codes(
    ranges,
    h_local,
    glob,
    smooth,
    small,
    dilated,
    v_local,
    v_offset,
    supported,
    ground,
    smooth_code,
    ground_code,
    nonsmooth_code,
    noise_code,
    unclassified_code,
):
    """:func:`combine` and :func:`class_codes` in one pass (the same three arrays).

    Returns
    -------
    segments : int32 (rows, cols)
    nonsmooth : bool (rows, cols)
    codes : uint8 (rows, cols)
    """
    R, C = h_local.shape
    seg = np.zeros((R, C), np.int32)
    nonsmooth = np.zeros((R, C), np.bool_)
    out = np.zeros((R, C), np.uint8)
    for r in range(R):
        for c in range(C):
            no_return = ranges[r, c] <= 0.0
            if not supported[r, c]:
                if not no_return:
                    out[r, c] = noise_code
                continue
            s = h_local[r, c]
            if small[r, c] or (s == 0 and dilated[r, c]):
                nonsmooth[r, c] = True
                v = v_local[r, c]
                seg[r, c] = v + v_offset if v > 0 else 0
                if not no_return:
                    out[r, c] = nonsmooth_code
            else:
                g = glob[s]
                seg[r, c] = g
                if no_return:
                    continue
                if smooth[r, c]:
                    out[r, c] = ground_code if (ground != 0 and g == ground) else smooth_code
                else:
                    out[r, c] = unclassified_code
    return seg, nonsmooth, out


@njit(cache=True, nogil=True)
def class_codes(
    ranges,
    supported,
    smooth,
    nonsmooth,
    segments,
    ground,
    smooth_code,
    ground_code,
    nonsmooth_code,
    noise_code,
    unclassified_code,
):
    """Step 6 (Sec. II-F): one code per slot. No return → 0; unsupported → noise; nonsmooth
    (``V_b``) → ``nonsmooth_code``; smooth → ``ground_code`` for segment ``ground`` (0: none)
    else ``smooth_code``; supported points in neither set → unclassified."""
    R, C = ranges.shape
    out = np.zeros((R, C), np.uint8)
    for r in range(R):
        for c in range(C):
            if ranges[r, c] <= 0.0:
                continue
            if not supported[r, c]:
                out[r, c] = noise_code
            elif nonsmooth[r, c]:
                out[r, c] = nonsmooth_code
            elif smooth[r, c]:
                out[r, c] = ground_code if (ground != 0 and segments[r, c] == ground) else smooth_code
            else:
                out[r, c] = unclassified_code
    return out
