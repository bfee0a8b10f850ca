"""The online detectors' fast kernels against simple references of the same definitions
(the kernels were rewritten for speed; their results must stay the same bit for bit)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from prc_slam.online import kernels as K
from prc_slam.online.car import oriented_box, oriented_boxes_of
from prc_slam.online.curb import _polylines, group_medians, possible_curbs, region_stats
from prc_slam.online.ground import _fenwick_add, _lowest_mean, _track_mode_ranked
from prc_slam.online.kernels import relabel
from prc_slam.online.spinning import _heights, graph_components, segment_tops

SETTINGS = settings(max_examples=60, deadline=None)


def stochastic(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.random((n, n)) + 1e-3
    return a / a.sum(axis=1, keepdims=True)


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 60))
def test_three_state_hmm_cusum_is_the_general_one(seed, n):
    rng = np.random.default_rng(seed)
    x = rng.choice([-90.0, 0.0, 90.0], n) + rng.normal(0, rng.choice([5.0, 40.0]), n)
    means = np.sort(rng.uniform(-150, 150, 3))
    a0, a1 = stochastic(rng, 3), stochastic(rng, 3)
    for sigma, h in [(20.0, 10.0), (float(rng.uniform(5, 50)), float(rng.uniform(0.5, 12)))]:
        fast = K._hmm_cusum3(x, means, sigma, a0, a1, h)
        general = K._hmm_cusum_n(x, means, sigma, a0, a1, h)
        np.testing.assert_array_equal(fast, general)
    assert K.hmm_cusum(x, means, 20.0, a0, a1, 10.0).shape == (n,)


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 80))
def test_evenly_spaced_three_state_hmm_cusum_is_the_general_one(seed, n):
    """The one-exp filter (means m1 - a, m1, m1 + a) gives the general filter's decisions; far
    samples (factors out of range) take the plain filter."""
    rng = np.random.default_rng(seed)
    m1, a = float(rng.uniform(-30, 30)), float(rng.uniform(20, 160))
    means = np.array([m1 - a, m1, m1 + a])
    means[2] = means[1] + (means[1] - means[0])  # evenly spaced in floating point
    x = rng.choice(means, n) + rng.normal(0, rng.choice([5.0, 40.0]), n)
    a0, a1 = stochastic(rng, 3), stochastic(rng, 3)
    for sigma, h in [(20.0, 10.0), (float(rng.uniform(5, 50)), float(rng.uniform(0.5, 12))), (1.0, 5.0)]:
        general = K._hmm_cusum_n(x, means, sigma, a0, a1, h)
        np.testing.assert_array_equal(K._hmm_cusum3(x, means, sigma, a0, a1, h), general)


def track_mode_reference(z, start, bandwidth):
    m = start
    for _ in range(100):
        window = z[np.abs(z - m) <= bandwidth]
        if len(window) == 0:
            return m
        new = window.mean()
        if abs(new - m) < 1e-3 * bandwidth:
            return new
        m = new
    return m


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 600))
def test_track_mode_is_mean_shift_from_its_start(seed, n):
    """The ground's z_d update (interleaved partial sums): the mode mean shift climbs to from
    ``start``, as a plain mean of each window gives it (to rounding)."""
    from prc_slam.online.ground import _track_mode

    rng = np.random.default_rng(seed)
    z = np.concatenate([rng.normal(-1.7, 0.05, n), rng.normal(-0.2, 0.3, n // 3)])
    start = float(rng.choice(z))
    assert abs(_track_mode(z, len(z), start, 0.2) - track_mode_reference(z, start, 0.2)) < 1e-9
    assert _track_mode(z, 0, start, 0.2) == start  # no samples: stays


#: the exact ``arccos`` to compare with: long double (64-bit mantissa on x86) is exact to ~1e-19,
#: far below the float64 ulp (2.2e-16 relative); where long double is only a double, no reference
EXACT = np.finfo(np.longdouble).nmant >= 63
needs_exact = pytest.mark.skipif(not EXACT, reason="long double is no wider than float64 here")
#: measured largest errors of :func:`K.arccos` (radians) against the exact value: 1.13 ulp over
#: 4e7 cosines (grid, near +-1, +-1/2 and 0); numpy's own ``np.arccos`` is within 0.82 ulp here
#: (glibc's within 0.5): so ours is within 1 + 0.5 / 0.82 < 2 ulp of numpy's on any machine
RAD_ULP_EXACT, RAD_ULP_NUMPY = 1.5, 2.0
#: :func:`K.arccos_into` (degrees): the radians' 1.13 ulp scaled by 180/pi plus the rounding of the
#: conversion, measured 2.70 ulp of the exact degrees
DEG_ULP_EXACT = 3.0


def ulp_error(ours: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """``|ours - exact|`` in units in the last place of the float64 nearest ``exact``."""
    return np.abs((ours.astype(np.longdouble) - exact) / np.spacing(exact.astype(np.float64))).astype(np.float64)


def cosines_over_the_domain() -> np.ndarray:
    """A dense grid of [-1, 1] with both endpoints, plus the ulps next to -1, -1/2, 0, 1/2 and 1
    (where the reduction switches branch or the result loses its leading bits) and a log-spaced
    approach to +-1 and 0."""
    one = np.spacing(1.0) / 2
    near = np.arange(20_000)
    tail = np.geomspace(1e-300, 0.5, 20_000)
    parts = [
        np.linspace(-1.0, 1.0, 2_000_001),
        1.0 - near * one, -1.0 + near * one, (near - 10_000) * 5e-324, (near - 10_000) * 1e-12,
        0.5 + (near - 10_000) * np.spacing(0.5), -0.5 + (near - 10_000) * np.spacing(0.5),
        1.0 - tail, -1.0 + tail, tail, -tail,
    ]  # fmt: skip
    c = np.concatenate(parts)
    assert c.min() == -1.0 and c.max() == 1.0
    return c


@njit(cache=True)
def arccos_of(c: np.ndarray) -> np.ndarray:
    """:func:`K.arccos` one scalar at a time (the kernel as the detectors inline it)."""
    out = np.empty_like(c)
    for k in range(len(c)):
        out[k] = K.arccos(c[k])
    return out


@needs_exact
def test_arccos_error_over_the_whole_domain():
    """:func:`K.arccos` within 1.5 ulp of the exact arccos and 2 ulp of numpy's everywhere in
    [-1, 1]; :func:`K.arccos_into` (degrees) within 3 ulp of the exact degrees. (The polynomial's
    coefficients are not compared with a refit: the fit's last digits follow the LAPACK kernels
    the CPU selects, while this error is the property the detectors rely on.)"""
    c = cosines_over_the_domain()
    exact = np.arccos(c.astype(np.longdouble))
    ours = arccos_of(c)
    assert ulp_error(ours, exact).max() <= RAD_ULP_EXACT
    assert (np.abs(ours - np.arccos(c)) / np.spacing(np.arccos(c))).max() <= RAD_ULP_NUMPY
    assert ours[c == 1.0].max() == 0.0 and np.all(ours[c == -1.0] == np.pi)
    deg = c.copy()
    K.arccos_into(deg, len(deg))
    assert ulp_error(deg, np.degrees(exact)).max() <= DEG_ULP_EXACT


@needs_exact
@SETTINGS
@given(
    st.one_of(
        st.floats(-1.0, 1.0),
        st.floats(0.49, 0.51),
        st.floats(-0.51, -0.49),
        st.floats(0.999999, 1.0),
        st.floats(-1.0, -0.999999),
        st.floats(-1e-6, 1e-6),
    )
)
def test_arccos_error_bound_holds_for_any_cosine(c):
    """The same bounds on any cosine hypothesis draws, near the seams at +-1/2, near +-1 and 0."""
    exact = np.arccos(np.longdouble(c))
    assert ulp_error(np.array([K.arccos(c)]), np.array([exact]))[0] <= RAD_ULP_EXACT
    assert abs(K.arccos(c) - np.arccos(c)) <= RAD_ULP_NUMPY * np.spacing(np.arccos(c))
    deg = np.array([c])
    K.arccos_into(deg, 1)
    assert ulp_error(deg, np.array([np.degrees(exact)]))[0] <= DEG_ULP_EXACT


def line_statistics_reference(xyz, valid, line, origin, min_step=0.0, centred=False):
    """The definition of :func:`K.line_statistics`, one angle at a time with ``_angle_deg``."""
    pts = np.array([s for s in line if s >= 0 and valid[s]], np.int64)
    n = len(pts)
    sv, phi = np.zeros(n), np.zeros(n)
    if n < 2:
        return pts, sv, phi
    z = np.array([0.0, 0.0, 1.0])
    prev = np.zeros(3)
    cum, nxt, lo = 0.0, 1, 0
    for k in range(n - 1):
        a, step = k, min_step
        if centred and min_step > 0.0:
            step = 0.5 * min_step
            while lo + 1 < k and K._dist2(xyz, pts[lo + 1], pts[k]) >= step * step:
                lo += 1
            a = lo
        nxt = max(nxt, k + 1)
        while nxt < n - 1 and K._dist2(xyz, pts[nxt], pts[k]) < step * step:
            nxt += 1
        d = xyz[pts[nxt]] - xyz[pts[a]]
        ra, rb = xyz[pts[k]] - origin, xyz[pts[k + 1]] - origin
        sign = -1.0 if k > 0 and (d[0] * prev[0] + d[1] * prev[1] + d[2] * prev[2]) < 0.0 else 1.0
        sv[k] = sign * K._angle_deg(d, z)
        if k > 0:
            cum += K._angle_deg(ra, rb)
        phi[k] = K._angle_deg(d, rb) + cum
        prev = d
    sv[-1], phi[-1] = sv[-2], phi[-2]
    return pts, sv, phi


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 40), st.sampled_from([(0.0, False), (0.3, False), (0.3, True)]))
def test_line_statistics_is_its_definition(seed, n, step):
    rng = np.random.default_rng(seed)
    xyz = rng.normal(0, 5, (n + 3, 3))
    xyz[rng.random(n + 3) < 0.1] = xyz[0]  # repeated points: zero-length steps
    valid = rng.random(n + 3) < 0.85
    line = np.full(n + 5, -1, np.int64)
    line[:n] = rng.permutation(n + 3)[:n]
    got = K.line_statistics(xyz, valid, line, np.zeros(3), *step)
    ref = line_statistics_reference(xyz, valid, line, np.zeros(3), *step)
    for g, r in zip(got, ref, strict=True):
        np.testing.assert_array_equal(g, r)


def possible_curbs_reference(xyz, codes, ground, valid, lines, z_line, t_high, look_back, under_eps, last_only):
    out = []
    for li, line in enumerate(lines):
        pts = [s for s in line if s >= 0 and valid[s]]
        first = max([k for k, s in enumerate(pts) if ground[s]], default=0) if last_only else 0
        found, searching = [], False
        for k in range(first, len(pts)):
            s = pts[k]
            if ground[s]:
                searching = True
            elif searching and xyz[s, 2] > z_line[li] + t_high:
                searching = False
            elif searching and codes[s] == 69:
                far = max([np.sqrt((xyz[q] ** 2).sum()) for q in pts[max(0, k - look_back) : k]], default=0.0)
                if far - np.sqrt((xyz[s] ** 2).sum()) <= under_eps:
                    found.append(s)
                    searching = False
        out.append(found)
    return out


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.booleans(), st.integers(1, 8))
def test_possible_curbs_is_its_definition(seed, last_only, look_back):
    rng = np.random.default_rng(seed)
    n_lines, width = 4, 24
    n = n_lines * width
    xyz = rng.normal(0, 3, (n, 3))
    codes = rng.choice(np.array([68, 69, 5], np.uint8), n)
    ground = rng.random(n) < 0.3
    valid = rng.random(n) < 0.9
    lines = rng.permutation(n).reshape(n_lines, width)
    lines[:, width - 3 :] = -1
    z_line = rng.normal(0, 1, n_lines)
    got = possible_curbs(xyz, codes, ground, valid, lines, z_line, 2.0, look_back, 0.01, last_only)
    ref = possible_curbs_reference(xyz, codes, ground, valid, lines, z_line, 2.0, look_back, 0.01, last_only)
    for g, r in zip(got, ref, strict=True):
        assert list(g[g >= 0]) == r


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_region_stats_and_group_medians(seed, by_column):
    rng = np.random.default_rng(seed)
    rows, cols, n = int(rng.integers(1, 7)), int(rng.integers(1, 9)), int(rng.integers(0, 6))
    regions = rng.integers(0, n + 1, (rows, cols)).astype(np.int32)
    z = rng.normal(0, 1, (rows, cols)).astype(np.float32)
    zmin, zmax, size, n_lines = region_stats(regions, z, n, by_column)
    line = np.broadcast_to(np.arange(cols)[None, :] if by_column else np.arange(rows)[:, None], (rows, cols))
    for k in range(1, n + 1):
        sel = regions == k
        assert size[k] == sel.sum()
        assert n_lines[k] == len(np.unique(line[sel]))
        assert zmin[k] == (z[sel].min() if sel.any() else np.inf)
        assert zmax[k] == (z[sel].max() if sel.any() else -np.inf)
    ids = regions.ravel()
    values = rng.normal(0, 30, ids.size).astype(np.float32)
    groups = np.arange(1, n + 1)
    med = group_medians(ids, values, groups)
    for g, m in zip(groups, med, strict=True):
        sel = values[ids == g]
        assert (np.isnan(m) and not len(sel)) or np.float32(m) == np.median(sel)


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_segment_tops_is_the_last_highest_return(seed):
    rng = np.random.default_rng(seed)
    rows, cols, n = int(rng.integers(1, 6)), int(rng.integers(1, 9)), int(rng.integers(0, 5))
    seg = rng.integers(0, n + 1, (rows, cols)).astype(np.int32)
    height = rng.choice([0.0, 0.5, 1.0, -0.0], (rows, cols)) + rng.choice([0.0, 0.1], (rows, cols))  # ties
    veg = rng.random((rows, cols)) < 0.4
    top_at, cnt, nveg = segment_tops(seg, n, height, veg)
    # the reference: a stable lexsort by (segment, height), the last of each segment
    flat = seg.ravel()
    sel = np.flatnonzero(flat)
    ref = np.zeros(n + 1, np.int64)
    if len(sel):
        by = np.lexsort((height.ravel()[sel], flat[sel]))
        last = np.r_[np.flatnonzero(np.diff(flat[sel][by])), len(by) - 1]
        ref[flat[sel][by][last]] = sel[by][last]
    np.testing.assert_array_equal(top_at, ref)
    np.testing.assert_array_equal(cnt, np.bincount(flat, minlength=n + 1))
    np.testing.assert_array_equal(nveg, np.bincount(flat, weights=veg.ravel(), minlength=n + 1))


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_car_heights_are_their_definition(seed):
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 6)), int(rng.integers(1, 9)))
    z = rng.choice([np.nan, np.inf, 0.0, 1.0], shape, p=[0.1, 0.05, 0.05, 0.8]) * rng.uniform(-3, 3, shape)
    z = z.astype(np.float32)
    zg = np.where(rng.random(shape) < 0.2, np.nan, rng.normal(-1.7, 0.2, shape))
    valid, ground = rng.random(shape) < 0.8, rng.random(shape) < 0.3
    height, cand, high, h_zero, h_down = _heights(z, zg, valid, ground, 0.25, 2.6)
    with np.errstate(invalid="ignore"):  # inf - inf
        ref = z - np.where(np.isnan(zg), np.inf, zg)
    np.testing.assert_array_equal(height, ref)
    np.testing.assert_array_equal(cand, valid & ~ground & (ref >= 0.25) & (ref <= 2.6))
    np.testing.assert_array_equal(high, valid & (ref > 2.6))
    np.testing.assert_array_equal(h_zero, np.where(np.isfinite(ref), ref, 0.0))
    np.testing.assert_array_equal(h_down, np.where(np.isfinite(ref), ref, -np.inf))


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.sampled_from([np.float32, np.float64]), st.booleans())
def test_boxes_in_one_kernel_are_oriented_box(seed, dtype, on_a_line):
    """The batch kernel against ``oriented_box`` (np.cov and np.linalg.eigh) per instance: the same
    boxes to rounding, the same axis sign (yaw), on elongated, round and degenerate footprints."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 5))
    parts, ids = [], []
    for k in range(1, n + 1):
        m = int(rng.integers(1, 300))
        p = rng.normal(size=(m, 3)) * [rng.uniform(0.05, 2.5), rng.uniform(0.05, 1.0), 0.5]
        t = rng.uniform(-np.pi, np.pi)
        p[:, :2] = p[:, :2] @ np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]]).T + rng.normal(0, 30, 2)
        if on_a_line:
            p[:, int(rng.integers(0, 2))] = p[0, 0]  # all on one line along x or y: no cross term
        parts.append(p)
        ids += [k] * m
    order = rng.permutation(len(ids))
    pts, ids = np.concatenate(parts)[order].astype(dtype), np.array(ids)[order]
    ids[rng.random(len(ids)) < 0.2] = 0
    got = oriented_boxes_of(ids, pts)
    ref = [oriented_box(pts[ids == k]) for k in range(1, n + 1) if (ids == k).any()]
    assert len(got) == len(ref)
    for k, g, r in zip(np.unique(ids[ids > 0]), got, ref, strict=True):
        assert g["points"] == r["points"]
        np.testing.assert_allclose([g["center"][2], g["size"][2]], [r["center"][2], r["size"][2]], atol=1e-9)
        # the axis moves by at most |dA| / gap (Davis-Kahan), |dA| the covariance's rounding (the
        # summation order of np.cov's BLAS product against the kernel's loop: below 1e-12 |A| for
        # 300 points); centre and size in the plane move with it times the footprint's extent
        xy = pts[ids == k, :2].astype(np.float64)
        w = np.linalg.eigvalsh(np.cov(xy.T)) if len(xy) > 2 else np.ones(2)
        spread = (w[1] + w[0]) / (w[1] - w[0]) if w[1] > w[0] else np.inf
        if spread > 1e6:  # a round footprint: no axis to compare
            continue
        turn = 1e-9 + 1e-12 * spread
        extent = np.abs(xy - xy.mean(axis=0)).max() + 1.0
        assert abs(g["yaw"] - r["yaw"]) <= turn
        np.testing.assert_allclose(g["center"][:2] + g["size"][:2], r["center"][:2] + r["size"][:2], atol=turn * extent)
    assert oriented_boxes_of(np.zeros(3, np.int64), np.zeros((3, 3))) == []


@SETTINGS
@given(st.lists(st.sampled_from([-1.9, -1.75, -1.7, -0.0, 0.0, 2.5]), min_size=1, max_size=40), st.integers(1, 8))
def test_lowest_mean_is_the_sorted_definition(z, k):
    z = np.array(z) + np.repeat(np.random.default_rng(len(z)).normal(0, 0.01, 1), len(z))
    m = min(k, len(z))
    total = 0.0
    for v in np.sort(z)[:m]:  # summed from the lowest up, as numba's mean (numpy's sum is pairwise)
        total += v
    assert _lowest_mean(z, k) == total / m


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(1, 70))
def test_first_runs_are_part_a_from_each_line_start(seed, n_lines, width):
    """The threaded pre-pass of the ground algorithm: each line's first potential-ground run, as
    :func:`_potential_ground` finds it on the line's returns (rows of any width, ``count`` used)."""
    from prc_slam.online.coarse import LineReturns
    from prc_slam.online.ground import _potential_ground, all_first_runs, ground_scratch

    rng = np.random.default_rng(seed)
    returns = LineReturns.empty(n_lines, width)
    returns.codes[:] = rng.choice(np.array([68, 68, 68, 69, 5], np.uint8), (n_lines, width))
    returns.phi[:] = rng.normal(0.0, rng.choice([2.0, 8.0]), (n_lines, width))
    returns.count[:] = rng.integers(0, width + 1, n_lines)
    run_a, run_b = all_first_runs(returns, 10, 10.0)
    scratch = ground_scratch(width)
    for li in range(n_lines):
        m = returns.count[li]
        codes, phi = returns.codes[li, :m], returns.phi[li, :m]
        assert (run_a[li], run_b[li]) == _potential_ground(codes, phi, 0, 10, 10.0, *scratch)


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 40))
def test_kernels_into_dirty_buffers_are_the_allocating_ones(seed, n):
    """The coarse classifier reuses one set of buffers for all its lines: what a line leaves
    behind must not reach the next (buffers filled with NaN / True here)."""
    rng = np.random.default_rng(seed)
    width = n + 5
    xyz = rng.normal(0.0, 5.0, (width, 3))
    valid = rng.random(width) > 0.2
    line = rng.permutation(width)[: n + 2].astype(np.int64)
    pts, sv, phi = np.full(width, 7, np.int64), np.full(width, np.nan), np.full(width, np.nan)
    work = np.full((2, width), np.nan)
    m = K.line_statistics_into(xyz, valid, line, np.zeros(3), 0.0, False, pts, sv, phi, work)
    ref = K.line_statistics(xyz, valid, line, np.zeros(3))
    np.testing.assert_array_equal(pts[:m], ref[0])
    np.testing.assert_array_equal(sv[:m], ref[1])
    np.testing.assert_array_equal(phi[:m], ref[2])
    x = rng.choice([-90.0, 0.0, 90.0], n) + rng.normal(0, 20.0, n)
    a0, a1 = stochastic(rng, 3), stochastic(rng, 3)
    out = np.ones(width, np.bool_)
    K.hmm_cusum3_into(x, np.array([-90.0, 0.0, 90.0]), 20.0, a0, a1, 10.0, out)
    np.testing.assert_array_equal(out[:n], K._hmm_cusum_n(x, np.array([-90.0, 0.0, 90.0]), 20.0, a0, a1, 10.0))
    out[:] = True
    K.mean_shift_cusum_into(x, 90.0, 0.0, 25.0, 5.0, out)
    np.testing.assert_array_equal(out[:n], K.mean_shift_cusum(x, 90.0, 0.0, 25.0, 5.0))


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 60), st.integers(0, 80))
def test_graph_components_number_as_scipy_does(seed, n, m):
    """The car path's grouping of grazing-linked segments: the components and their numbering of
    ``scipy.sparse.csgraph.connected_components`` (which it replaced)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, n, m), rng.integers(0, n, m)
    _, expected = connected_components(coo_matrix((np.ones(m), (a, b)), shape=(n, n)), directed=False)
    np.testing.assert_array_equal(graph_components(n, a, b), expected)


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 30), st.integers(1, 30), st.integers(1, 50))
def test_relabel_is_lookup(seed, rows, cols, n):
    rng = np.random.default_rng(seed)
    seg = rng.integers(0, n + 1, (rows, cols)).astype(np.int32)
    lut = rng.integers(-5, 100, n + 1).astype(np.int32)
    got = relabel(seg, lut)
    assert got.dtype == lut.dtype and got.shape == seg.shape
    np.testing.assert_array_equal(got, lut[seg])


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 60), st.integers(0, 80))
def test_union_find_components_are_the_graphs(seed, n, m):
    """Every edge's ends share a component id, ids count up in the order of each component's
    first node, and two nodes share an id only when a path of edges joins them."""
    from prc_slam.util import unionfind as uf

    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, n, m), rng.integers(0, n, m)
    parent = np.arange(n)
    for x, y in zip(a, b, strict=True):
        uf.union(parent, x, y)
    comp = uf.component_ids(parent)
    assert (comp[a] == comp[b]).all()
    first = np.unique(comp, return_index=True)[1]
    assert (np.diff(first) > 0).all() and comp[0] == 0
    reach = np.eye(n, dtype=bool)
    reach[a, b] = reach[b, a] = True
    for _ in range(int(np.ceil(np.log2(n))) + 1):  # transitive closure by squaring
        reach = (reach.astype(np.int64) @ reach.astype(np.int64)) > 0
    np.testing.assert_array_equal(comp[:, None] == comp[None, :], reach)


def polylines_reference(regions, ok, line_index, xyz):
    """Curb polylines by numpy (group by region and line with ``np.unique``, means by
    ``np.bincount``): the definition :func:`prc_slam.online.curb.polyline_means` implements."""
    flat = regions.ravel()
    members = np.flatnonzero(flat)
    members = members[ok[flat[members]]]
    if not len(members):
        return []
    key = flat[members].astype(np.int64) * (1 << 20) + line_index[np.unravel_index(members, regions.shape)]
    uniq, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    pts = xyz.reshape(-1, 3)[members].astype(np.float64)
    mean = np.stack([np.bincount(inv, weights=pts[:, c]) for c in range(3)], axis=1) / counts[:, None]
    cuts = np.flatnonzero(np.diff(uniq >> 20)) + 1
    return [m.astype(np.float32) for m in np.split(mean, cuts)]


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 12), st.integers(1, 40), st.booleans())
def test_curb_polylines_are_their_definition(seed, rows, cols, by_column):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 6))
    regions = np.where(rng.random((rows, cols)) < 0.4, rng.integers(0, n + 1, (rows, cols)), 0).astype(np.int32)
    ok = rng.random(n + 1) < 0.7
    ok[0] = False
    xyz = rng.normal(0, 10, (rows, cols, 3)).astype(rng.choice([np.float32, np.float64]))
    index = np.arange(cols)[None, :] if by_column else np.arange(rows)[:, None]
    line_index = np.broadcast_to(index, (rows, cols))
    got = _polylines(regions, ok, line_index, xyz)
    ref = polylines_reference(regions, ok, line_index, xyz)
    assert len(got) == len(ref)
    for g, r in zip(got, ref, strict=True):
        assert g.dtype == np.float32
        np.testing.assert_array_equal(g, r)


@njit(cache=False)
def _numba_argsort(a):
    return np.argsort(a)


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 90), st.sampled_from(["spread", "ties", "nan"]))
def test_argsort_into_is_numbas_argsort(seed, n, kind):
    """The ground's allocation-free argsort gives numba's ``np.argsort`` permutation exactly (quicksort:
    ties keep the order its partitions leave them in, NaNs last), into a dirty buffer longer than the data."""
    from prc_slam.online.ground import ARGSORT_STACK, argsort_into

    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, 10.0, n)
    if kind == "ties":
        a = np.round(a / 5.0) * 5.0  # a handful of distinct values, each many times
    elif kind == "nan" and n:
        a[rng.random(n) < 0.2] = np.nan
    idx = np.full(n + 7, -3, np.int64)
    argsort_into(a, idx, np.full((ARGSORT_STACK, 2), -1, np.int64))
    np.testing.assert_array_equal(idx[:n], _numba_argsort(a))
    assert (idx[n:] == -3).all()


def test_argsort_into_hand_computed():
    """Equal values in numba's quicksort order (insertion sort under 15 samples: stable), NaN last."""
    from prc_slam.online.ground import ARGSORT_STACK, argsort_into

    idx = np.empty(5, np.int64)
    argsort_into(np.array([3.0, np.nan, 1.0, 3.0, -2.0]), idx, np.empty((ARGSORT_STACK, 2), np.int64))
    assert idx.tolist() == [4, 2, 0, 3, 1]


@njit(cache=False)
def _grow_single_mode_eager(x, start, end, end_max, bandwidth):
    """Part (a)'s growth as it was written before its ranks and trees were made lazily: every sample
    ranked (numba's ``np.argsort``) and entered in the Fenwick trees as it comes."""
    if end >= end_max:
        return end_max
    vals = x[start:end_max]
    nv = vals.shape[0]
    order = np.argsort(vals)
    srt = np.empty(nv)
    rank = np.empty(nv, np.int64)
    for i in range(nv):
        srt[i] = vals[order[i]]
        rank[order[i]] = i
    cnt = np.zeros(nv + 1)
    tot = np.zeros(nv + 1)
    lo = np.inf
    hi = -np.inf
    for e in range(nv):
        v = vals[e]
        _fenwick_add(cnt, rank[e], 1.0)
        _fenwick_add(tot, rank[e], v)
        lo = min(lo, v)
        hi = max(hi, v)
        if e + start < end or hi - lo <= bandwidth:
            continue
        a = _track_mode_ranked(srt, cnt, tot, lo, bandwidth)
        b = _track_mode_ranked(srt, cnt, tot, hi, bandwidth)
        if abs(b - a) >= bandwidth / 2:
            return e + start
    return end_max


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 80), st.sampled_from([0.5, 3.0, 8.0, 20.0]))
def test_growth_with_lazy_ranks_is_the_eager_one(seed, n, spread):
    """Part (a)'s growth, whose ranks and Fenwick trees wait until the samples spread over one bandwidth
    (then take the samples so far in order), ends where the eager form ends, from any start and first end,
    on narrow, wide, drifting and tied line angles."""
    from prc_slam.online.ground import grow_single_mode

    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, spread, n) + np.linspace(0.0, rng.choice([0.0, 30.0]), n)
    if rng.random() < 0.3:
        x = np.round(x)
    start = int(rng.integers(0, n))
    end = int(rng.integers(start, n + 1))
    for bandwidth in (1.0, 10.0):
        assert grow_single_mode(x, start, end, n, bandwidth) == _grow_single_mode_eager(x, start, end, n, bandwidth)


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 200), st.integers(1, 12))
def test_curb_region_lookups_are_numpys(seed, n_slots, n_ids):
    """Sec. 6's per-region lookups over the image: the slots of flagged regions and the mask of accepted
    ones, as numpy's ``np.flatnonzero(flags[ids])`` and ``ok[regions]`` give them."""
    from prc_slam.online.curb import flagged_slots

    rng = np.random.default_rng(seed)
    ids = rng.integers(0, n_ids, n_slots).astype(np.int32)
    flags = rng.random(n_ids) < 0.4
    got = flagged_slots(ids, flags)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, np.flatnonzero(flags[ids]))
    regions = ids.reshape(1, -1) if n_slots % 3 else ids.reshape(-1, 3) if n_slots else ids.reshape(0, 3)
    mask = relabel(regions, flags)
    assert mask.dtype == np.bool_
    np.testing.assert_array_equal(mask, flags[regions])


def test_flagged_slots_hand_computed():
    assert flagged_slots_of([0, 2, 1, 2, 0], [False, True, True]) == [1, 2, 3]
    assert flagged_slots_of([], [True]) == []


def flagged_slots_of(ids: list[int], flags: list[bool]) -> list[int]:
    from prc_slam.online.curb import flagged_slots

    return flagged_slots(np.array(ids, np.int64), np.array(flags)).tolist()
