"""Support condition, eqs. (3)-(8), and the background extension, eq. (9): hand-computed cases."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from prc_slam.config import PRCConfig
from prc_slam.prc import kernels, supported_mask
from prc_slam.prc.algorithm import support_thresholds

CFG = PRCConfig(xi_s=1.0, xi_p=1.0)


def _support(r: np.ndarray, cfg: PRCConfig = CFG, wrap: bool = False) -> np.ndarray:
    r = r.astype(np.float32)
    return supported_mask(r, cfg, None, wrap)


def test_counts_hand_computed():
    # 3 x 9 block, centre pixel (1, 4) at range 10. In-slice neighbours (eq. 8): columns 0..8
    # except 4 in row 1; adjacent-slice (eq. 7): columns 3, 4, 5 in rows 0 and 2.
    r = np.full((3, 9), 50.0, dtype=np.float32)
    r[1, 4] = 10.0
    r[1, [1, 6, 8]] = [10.5, 9.2, 10.99]  # |dr| = 0.5, 0.8, 0.99 < 1 -> 3 in-slice supporters
    r[1, 3] = 11.0  # |dr| = 1.0, not < xi_p: no support (strict inequality of eq. 6)
    r[0, 5] = 10.2
    r[2, 3] = 9.7  # two adjacent-slice supporters
    r[0, 8] = 10.0  # outside N_adj (column 8): must not count
    xs, xp = support_thresholds(r, CFG, None)
    c_adj, c_in = kernels.support_counts(r, xs, xp, 4, False)
    assert c_in[1, 4] == 3
    assert c_adj[1, 4] == 2
    # eq. (4) with rho_c = 1/3: C_in >= 8/3 (i.e. 3) and C_adj >= 6/3 = 2 -> supported
    assert _support(r)[1, 4]
    r2 = r.copy()
    r2[2, 3] = 50.0  # only one adjacent supporter left
    assert not _support(r2)[1, 4]
    r3 = r.copy()
    r3[1, 8] = 50.0  # only two in-slice supporters left
    assert not _support(r3)[1, 4]


def test_no_return_neither_gets_nor_gives_support():
    r = np.full((3, 12), 5.0, dtype=np.float32)
    r[1, 6] = 0.0
    s = _support(r)
    assert not s[1, 6]
    xs, xp = support_thresholds(r, CFG, None)
    c_adj, c_in = kernels.support_counts(r, xs, xp, 4, False)
    assert c_in[1, 5] == 7  # neighbour at column 6 has no return
    assert c_adj[0, 6] == 2  # (1, 6) does not count for (0, 6)


def test_wrap_columns_connect_first_and_last():
    r = np.zeros((3, 20), dtype=np.float32)
    r[:, [17, 18, 19, 0, 1]] = 5.0
    assert not _support(r, wrap=False)[1, 0]
    assert _support(r, wrap=True)[1, 0]


def test_adaptive_thresholds_scale_with_range():
    from prc_slam.scan import SpinningSensor

    sensor = SpinningSensor.create(np.radians([-10.0, -9.0, -8.0]), 360)
    r = np.full((3, 360), 40.0, dtype=np.float32)
    cfg = PRCConfig(adaptive=True, adaptive_incidence_deg=80.0)
    xs, xp = support_thresholds(r, cfg, sensor)
    # spacing at normal incidence r * dtheta, scaled by tan(80 deg)
    assert np.allclose(xs, 40.0 * np.radians(1.0) * np.tan(np.radians(80.0)), rtol=1e-5)
    assert np.allclose(xp, max(1.0, 40.0 * np.radians(1.0) * np.tan(np.radians(80.0))), rtol=1e-5)
    near = np.full((3, 360), 1.0, dtype=np.float32)
    xs_near, _ = support_thresholds(near, cfg, sensor)
    assert np.allclose(xs_near, cfg.xi_s)  # never below the paper's threshold


finite_ranges = arrays(
    np.float32, st.tuples(st.integers(2, 8), st.integers(5, 30)), elements=st.floats(0.5, 120.0, width=32)
)


@settings(max_examples=60, deadline=None)
@given(finite_ranges, st.booleans())
def test_xi_to_zero_everything_is_noise(r, wrap):
    cfg = PRCConfig(xi_s=0.0, xi_p=0.0)
    assert not _support(r, cfg, wrap).any()


@settings(max_examples=60, deadline=None)
@given(finite_ranges, st.booleans())
def test_xi_to_infinity_nothing_is_noise(r, wrap):
    cfg = PRCConfig(xi_s=1e9, xi_p=1e9)
    assert _support(r, cfg, wrap).all()


_RANGES = st.one_of(st.just(0.0), st.floats(0.125, 30.0, width=32))


@settings(max_examples=60, deadline=None)
@given(
    st.one_of(
        # narrow images: the per-slot path; wide ones (> 2 * reach + 1 columns): the row-wise one
        arrays(np.float32, st.tuples(st.integers(1, 7), st.integers(1, 25)), elements=_RANGES),
        arrays(np.float32, st.tuples(st.integers(1, 5), st.integers(26, 70)), elements=_RANGES),
    ),
    st.floats(0.01, 5.0),
    st.floats(0.01, 5.0),
    st.booleans(),
)
def test_fused_kernel_equals_reference_kernels(r, xi_s, xi_p, wrap):
    """The one-pass kernel gives the same S_b and G_b as the plain counting kernel of eqs.
    (5)-(8) and the separate eq. (9) kernel, on narrow images (neighbourhoods that overlap
    across the wrap, counted slot by slot) and wide ones (counted row by row)."""
    cfg = PRCConfig(xi_s=xi_s, xi_p=xi_p, gradient_axes="both")
    xs, xp = support_thresholds(r, cfg, None)
    c_adj, c_in = kernels.support_counts(r, xs, xp, 4, wrap)
    expected = (r > 0) & (c_in >= 3) & (c_adj >= 2)
    grad_ref = kernels.gradient_background(r, expected, 0.3, 0.05, False, wrap, True)
    sup, grad, one_sided = kernels.support_and_gradient(
        r, xs, xp, 4, 3, 2, 0.3, 0.05, False, wrap, True, True, 4, xs, xp, False
    )
    np.testing.assert_array_equal(sup, expected)
    np.testing.assert_array_equal(one_sided, (r > 0) & ((c_in >= 3) != (c_adj >= 2)))
    np.testing.assert_array_equal(grad, grad_ref)
    # per-slot thresholds (adaptive mode): symmetric max(xi_i, xi_j) in both kernels
    rng = np.random.default_rng(int(r.size))
    xs2 = (xs * rng.uniform(0.5, 3.0, r.shape)).astype(np.float32)
    xp2 = (xp * rng.uniform(0.5, 3.0, r.shape)).astype(np.float32)
    c_adj, c_in = kernels.support_counts(r, xs2, xp2, 4, wrap)
    sup2, _, _ = kernels.support_and_gradient(
        r, xs2, xp2, 4, 3, 2, 0.3, 0.05, False, wrap, True, False, 4, xs, xp, False
    )
    np.testing.assert_array_equal(sup2, (r > 0) & (c_in >= 3) & (c_adj >= 2))
    # N_in-slice as the closest returns within a reach (skipping no-returns): same in both kernels
    for reach in (6, 12):
        c_adj, c_in = kernels.support_counts(r, xs2, xp2, 4, wrap, reach)
        sup3, _, one3 = kernels.support_and_gradient(
            r, xs2, xp2, 4, 3, 2, 0.3, 0.05, False, wrap, True, False, reach, xs, xp, False
        )
        np.testing.assert_array_equal(sup3, (r > 0) & (c_in >= 3) & (c_adj >= 2))
        np.testing.assert_array_equal(one3, (r > 0) & ((c_in >= 3) != (c_adj >= 2)))
        # second pass (one-sided rule): unsupported returns meeting either condition under (xs, xp)
        _, _, one4 = kernels.support_and_gradient(
            r, xs2, xp2, 4, 3, 2, 0.3, 0.05, False, wrap, True, False, reach, xs, xp, True
        )
        t_adj, t_in = kernels.support_counts(r, xs, xp, 4, wrap, reach)
        np.testing.assert_array_equal(one4, (r > 0) & ~sup3 & ((t_in >= 3) | (t_adj >= 2)))


def test_in_slice_reach_skips_dropouts():
    """Hand-computed: a return whose in-slice neighbours within 4 columns are mostly dropouts
    lacks support over the paper's slots and has it over the closest returns."""
    row = np.array([5.0, 5.0, 0, 0, 0, 5.0, 0, 0, 0, 5.0, 5.0, 5.0, 5.0], dtype=np.float32)
    r = np.vstack([row, row, row])
    xs = np.full(r.shape, 1.0, np.float32)
    _, c_in = kernels.support_counts(r, xs, xs, 4, False)
    assert c_in[1, 5] == 2  # columns 1 and 9 only
    _, c_in = kernels.support_counts(r, xs, xs, 4, False, 12)
    assert c_in[1, 5] == 6  # columns 0, 1 on the left, 9-12 on the right


def _grad(row, literal=False, alpha=0.3, d_c=0.05):
    r = np.asarray([row], dtype=np.float32)
    return kernels.gradient_background(r, np.ones_like(r, bool), alpha, d_c, literal, False, False)[0]


def test_eq9_linear_ramp_stays_foreground():
    # (r_i - r_{i-1}) / (r_{i+1} - r_{i-1}) = 0.5 on a linear ramp: 0.3 < 0.5 < 0.7
    g = _grad([10.0, 10.2, 10.4, 10.6, 10.8])
    assert not g[1:-1].any()


def test_eq9_kink_goes_to_background():
    # at index 2: a = 0.1, b = 1.0 -> ratio 0.1 / 1.1 = 0.09 < alpha -> G
    g = _grad([10.0, 10.1, 10.2, 11.2, 12.2])
    assert g[2]
    assert not g[1] and not g[3]


def test_eq9_ratio_boundaries():
    # alpha = 0.25 (exact in binary): ratio exactly 0.25 is outside the open interval
    assert _grad([8.0, 9.0, 12.0], alpha=0.25)[1]
    assert _grad([8.0, 9.0, 12.0], alpha=0.25, literal=True)[1]
    assert not _grad([8.0, 9.25, 12.0], alpha=0.25)[1]  # 0.3125
    assert not _grad([8.0, 9.25, 12.0], alpha=0.25, literal=True)[1]


def test_eq9_literal_form_rejects_falling_and_flat_ranges():
    falling = [12.0, 11.8, 11.6, 11.4, 11.2]
    flat = [10.0, 10.0, 10.0, 10.0]
    # as printed, max(r_{i+1} - r_{i-1}, d_c) = d_c for falling ranges: ratio < 0 -> G
    assert _grad(falling, literal=True)[1:-1].all()
    assert _grad(flat, literal=True)[1:-1].all()
    # the symmetric form agrees with the printed one on rising ramps and keeps these
    assert not _grad(falling)[1:-1].any()
    assert not _grad(flat)[1:-1].any()
    rising = [10.0, 10.2, 10.4, 10.6, 11.9, 12.0]
    np.testing.assert_array_equal(_grad(rising, literal=True)[1:-1], _grad(rising)[1:-1])


def test_eq9_both_axes_catches_crease_across_scan_lines():
    # a column rising along a ground then hitting a wall: crease between rows 2 and 3
    col = np.array([4.0, 6.0, 8.0, 8.2, 8.4, 8.6], dtype=np.float32)
    r = np.repeat(col[:, None], 5, axis=1)
    sup = np.ones_like(r, bool)
    only_in = kernels.gradient_background(r, sup, 0.3, 0.05, False, False, False)
    both = kernels.gradient_background(r, sup, 0.3, 0.05, False, False, True)
    assert not only_in.any()
    assert both[2].all() and not both[4].any()


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 2**31 - 1),
    st.booleans(),
    st.sampled_from([None, 60.0, 85.0]),
    st.floats(0.0, 89.0),
    st.floats(0.01, 2.0),
)
def test_spinning_thresholds_equal_support_thresholds(seed, adaptive, one_sided, beta, xi):
    """The one-pass thresholds of a spinning block are support_thresholds' values, bit for bit."""
    from prc_slam.prc.algorithm import _all_thresholds
    from prc_slam.scan import SpinningSensor

    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(1, 9)), int(rng.integers(5, 60))
    sensor = SpinningSensor.create(np.sort(rng.uniform(-0.4, 0.2, rows)), cols)
    r = (rng.uniform(0.0, 90.0, (rows, cols)) * (rng.random((rows, cols)) < 0.8)).astype(np.float32)
    cfg = PRCConfig(
        adaptive=adaptive, adaptive_incidence_deg=beta, one_sided_incidence_deg=one_sided, xi_s=xi, xi_p=2 * xi
    )
    got = _all_thresholds(r, cfg, sensor, one_sided is not None)
    want = support_thresholds(r, cfg, sensor) if adaptive else (np.full_like(r, xi), np.full_like(r, 2 * xi))
    if one_sided is not None:
        want = (*want, *support_thresholds(r, cfg, sensor, one_sided))
    else:
        want = (*want, *want)
    for a, b in zip(got, want, strict=True):
        assert a.dtype == np.float32 and np.array_equal(a, b)
