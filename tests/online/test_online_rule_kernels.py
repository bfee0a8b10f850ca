"""The kernels of the range-noise and beam-spacing rules against the vectorised numpy forms they replaced
(one pass over the image each instead of many temporaries; the results must stay the same bit for bit)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam import labels as L
from prc_slam.online.curb import beam_gap_up, group_medians, region_spacing
from prc_slam.online.detector import overlay_labels
from prc_slam.online.noise import (
    beam_gaps,
    coarse_vegetation_spacing,
    column_runs,
    labelled_over_spacing,
    ring_smooth_at,
    ring_surface,
)
from prc_slam.online.spinning import (
    hidden_floor,
    missing_top_gaps,
    row_spans,
    segment_counts,
    segment_features,
    segment_tops,
    segment_tops_within,
)
from prc_slam.scan import Scan, SpinningSensor

SETTINGS = settings(max_examples=40, deadline=None)


def ring_surface_numpy(xyz, valid, ranges, baseline, max_turn_deg, r, c, max_offset=4):
    """The vectorised form of :func:`ring_surface` at the slots ``(r, c)`` (valid ones)."""
    cols = valid.shape[1]
    step = np.asarray(ranges, dtype=np.float64)[r, c] * (2.0 * np.pi / cols)
    k = np.clip(np.ceil(baseline / np.maximum(step, 1e-9)), 1, max_offset).astype(np.int64)
    ends = []
    for sign in (-1, 1):
        off = np.zeros(len(r), np.int64)
        for j in range(max_offset, 0, -1):
            hit = (j >= k) & valid[r, (c + sign * j) % cols]
            off[hit] = j
        ends.append(off)
    before, after = ends
    ok = (before > 0) & (after > 0)
    p = np.asarray(xyz[r, c], dtype=np.float64)
    d1 = p - xyz[r, (c - before) % cols]
    d2 = xyz[r, (c + after) % cols] - p
    n1, n2 = np.linalg.norm(d1, axis=1), np.linalg.norm(d2, axis=1)
    ok &= (n1 < 3.0 * before * step) & (n2 < 3.0 * after * step) & (n1 > 0) & (n2 > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.einsum("ij,ij->i", d1, d2) / (n1 * n2)
    return ok & (cos > np.cos(np.radians(max_turn_deg)))


def test_ring_smooth_at_hand_computed():
    """Five returns 0.1 m apart along a straight ring, the fourth bent 0.2 m out: the second return turns
    by 0 deg, the third by 63 deg, the bent one by 127 deg; the ends, with no return within ``max_offset``
    columns on one side, are no surface."""
    cols = 64
    xyz = np.zeros((1, cols, 3), np.float32)
    xyz[0, :5, 0] = [0.0, 0.1, 0.2, 0.3, 0.4]
    xyz[0, :5, 1] = 10.0
    xyz[0, 3, 1] = 10.2  # bent
    valid = np.zeros((1, cols), bool)
    valid[0, :5] = True
    ranges = np.full((1, cols), 10.0, np.float32)  # 0.98 m a column: k = 1
    got = ring_smooth_at(xyz, valid, ranges, 0.05, np.cos(np.radians(45.0)), np.zeros(5, np.int64), np.arange(5), 4)
    # column 0 has no return within 4 columns before it (60-63 are missing); 1 is straight; 2, 3 and 4 bend
    assert got.tolist() == [False, True, False, False, False]


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_ring_smooth_at_is_the_vectorised_form(seed):
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(1, 5)), int(rng.integers(3, 40))
    ranges = rng.uniform(0.5, 30.0, (rows, cols)).astype(np.float32)
    valid = rng.random((rows, cols)) < rng.uniform(0.3, 1.0)
    ranges[~valid] = 0.0
    az = 2.0 * np.pi * (np.arange(cols) + 0.5) / cols
    xyz = np.stack([ranges * np.cos(az), ranges * np.sin(az), rng.normal(0, 0.05, (rows, cols))], -1)
    xyz = xyz.astype(np.float32)
    baseline = float(rng.choice([0.0, 0.05, 0.12, 2.0]))
    r, c = np.nonzero(valid)
    turn = float(rng.uniform(5.0, 80.0))
    got = ring_smooth_at(xyz, valid, ranges, baseline, np.cos(np.radians(turn)), r, c, 4)
    np.testing.assert_array_equal(got, ring_surface_numpy(xyz, valid, ranges, baseline, turn, r, c))
    np.testing.assert_array_equal(ring_surface(xyz, valid, ranges, baseline, turn)[r, c], got)


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_coarse_vegetation_spacing_and_column_runs_are_the_masks_they_replaced(seed):
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(2, 12)), int(rng.integers(1, 20))
    alt = np.radians(rng.permutation(np.linspace(-20.0, 10.0, rows)))  # rows in any order
    codes = rng.choice(np.array([0, 5, 68, 69], np.uint8), (rows, cols))
    ground = rng.random((rows, cols)) < 0.2
    ranges = rng.uniform(0.5, 20.0, (rows, cols)).astype(np.float32)
    gap = beam_gaps(alt)
    bound = float(rng.uniform(0.0, 0.5))
    slots, spacing = coarse_vegetation_spacing(codes, ground, ranges, gap, bound, 5)
    # the numpy form: every vegetation return other than ground, its column spacing, those under the bound
    r, c = np.nonzero((codes == 5) & ~ground)
    ref_spacing = ranges[r, c] * gap[r]
    under = ref_spacing < bound
    np.testing.assert_array_equal(slots, (r * cols + c)[under])
    np.testing.assert_array_equal(spacing, ref_spacing[under])
    # the runs: each such column from RUN_MARGIN beams below its lowest slot to as many above its highest
    order = np.argsort(alt, kind="stable")
    lines = np.ascontiguousarray(np.arange(rows * cols).reshape(rows, cols)[order].T)
    rank = np.empty(rows, np.int64)
    rank[order] = np.arange(rows)
    margin = int(rng.integers(0, 4))
    runs = column_runs(lines, rank, slots, margin)
    col, pos = c[under], rank[r[under]]
    cols_u = np.unique(col)
    assert runs.shape[0] == len(cols_u)
    for i, cc in enumerate(cols_u):
        lo = max(pos[col == cc].min() - margin, 0)
        hi = min(pos[col == cc].max() + margin, rows - 1)
        want = lines[cc, lo : hi + 1]
        np.testing.assert_array_equal(runs[i, : len(want)], want)
        assert (runs[i, len(want) :] == -1).all()


def test_labelled_over_spacing_hand_computed():
    """Beams at 0 and 1 deg at 10 and 20 m: each row's spacing is range x 1 deg (0.1745 / 0.349 m); over
    0.2 m only the 20 m vegetation return; with no bound, every vegetation return."""
    labels = np.array([[5, 5, 68], [5, 69, 5]], np.uint8)
    ranges = np.array([[10.0, 20.0, 20.0], [10.0, 20.0, 20.0]], np.float32)
    gap = beam_gaps(np.radians([0.0, 1.0]))
    assert labelled_over_spacing(labels, ranges, gap, 0.2, 5).tolist() == [1, 5]
    assert labelled_over_spacing(labels, ranges, gap, 0.0, 5).tolist() == [0, 1, 3, 5]


def missing_top_gaps_numpy(valid, alt, gaps, mount, max_range):
    """The vectorised form of :func:`missing_top_gaps` (every slot)."""
    rows, cols = valid.shape
    reach = np.where(alt < 0, mount / np.tan(-np.minimum(alt, -1e-9)), np.inf)
    should_hit = (alt < 0) & (reach < max_range)
    idx = np.arange(rows * cols)
    r0, c = idx // cols, idx % cols
    out = gaps[r0].astype(np.float64)
    r = r0 + 1
    live = r < rows
    while live.any():
        rr = np.minimum(r, rows - 1)
        hit = live & valid[rr, c]
        out[hit] = alt[rr[hit]] - alt[r0[hit]]
        live &= ~hit & should_hit[rr]
        r = r + 1
        live &= r < rows
    return out.reshape(rows, cols)


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_missing_top_gaps_is_the_vectorised_form(seed):
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(1, 10)), int(rng.integers(1, 8))
    alt = np.sort(rng.uniform(-0.4, 0.2, rows))
    gaps = np.append(np.diff(alt), 0.0)
    valid = rng.random((rows, cols)) < 0.5
    mount, far = float(rng.uniform(0.5, 3.0)), float(rng.uniform(5.0, 60.0))
    ref = missing_top_gaps_numpy(valid, alt, gaps, mount, far)
    np.testing.assert_array_equal(missing_top_gaps(valid, alt, gaps, mount, far), ref)
    at = rng.integers(0, rows * cols, 5)
    np.testing.assert_array_equal(missing_top_gaps(valid, alt, gaps, mount, far, at), ref.ravel()[at])


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_segment_tops_within_is_tops_and_counts_over_a_mask(seed):
    rng = np.random.default_rng(seed)
    rows, cols, n = int(rng.integers(1, 7)), int(rng.integers(1, 9)), int(rng.integers(0, 5))
    seg = rng.integers(0, n + 1, (rows, cols)).astype(np.int32)
    height = rng.choice([0.0, 0.5, 1.0], (rows, cols)) + rng.choice([0.0, 0.1], (rows, cols))
    veg = rng.random((rows, cols)) < 0.4
    valid = rng.random((rows, cols)) < 0.8
    ranges = rng.uniform(1.0, 30.0, (rows, cols)).astype(np.float32)
    local_gap = rng.uniform(0.001, 0.03, rows)
    res = float(rng.uniform(0.0, 0.5))
    resolved = (ranges * local_gap[:, None] <= res) & valid
    top_at, cnt, nveg = segment_tops_within(seg, n, height, veg, ranges, local_gap, res, valid)
    ref_top, _, ref_veg = segment_tops(seg, n, height, veg & resolved)
    np.testing.assert_array_equal(top_at, ref_top)
    np.testing.assert_array_equal(cnt, segment_counts(seg, n, resolved))
    np.testing.assert_array_equal(nveg, ref_veg)


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_hidden_floor_is_the_elementwise_form_on_segments(seed):
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(1, 6)), int(rng.integers(1, 9))
    xyz = rng.normal(0.0, 10.0, (rows, cols, 3)).astype(np.float32)
    zg = rng.normal(-1.7, 0.3, (rows, cols))
    zg[rng.random((rows, cols)) < 0.2] = np.nan  # no ground level
    ranges = np.linalg.norm(xyz, axis=-1).astype(np.float32)
    seg = (rng.random((rows, cols)) < 0.6).astype(np.int32)
    tan_low = np.tan(np.float64(rng.uniform(-0.5, -0.05)))
    gap_down = rng.uniform(0.0, 0.03, rows)
    rho = np.hypot(xyz[..., 0], xyz[..., 1])
    with np.errstate(invalid="ignore"):
        below = np.maximum(rho * tan_low - zg, 0.0)
    below = np.where(np.isfinite(below), below, 0.0)
    on = seg > 0
    for lowest, gaps in ((True, gap_down), (False, gap_down), (True, np.zeros(0))):
        want = (below if lowest else 0.0) + (ranges * gap_down[:, None] if len(gaps) else 0.0)
        got = hidden_floor(seg, xyz, zg, ranges, tan_low, lowest, gaps)
        np.testing.assert_array_equal(got[on], np.broadcast_to(want, (rows, cols))[on])
        assert (got[~on] == 0.0).all()


def test_row_spans_hand_computed():
    seg = np.array([[0, 0, 0, 0], [0, 3, 0, 1], [2, 0, 0, 0]], np.int32)
    lo, hi = row_spans(seg)
    assert lo.tolist() == [0, 1, 0] and hi.tolist() == [0, 4, 1]


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_segment_features_over_row_spans_are_those_over_every_slot(seed):
    """A far segment added at both ends of every row stretches every span over the whole row: the features
    of the others do not change (a ring's run state starts afresh at a change of segment)."""
    rng = np.random.default_rng(seed)
    rows, cols, n = int(rng.integers(1, 6)), int(rng.integers(3, 16)), int(rng.integers(1, 4))
    seg = np.where(rng.random((rows, cols)) < 0.5, rng.integers(1, n + 1, (rows, cols)), 0).astype(np.int32)
    seg[:, 0] = seg[:, -1] = 0
    xyz = rng.normal(0.0, 2.0, (rows, cols, 3)).astype(np.float32)
    height = rng.uniform(0.0, 2.5, (rows, cols))
    valid = rng.random((rows, cols)) < 0.9
    floor = rng.uniform(0.0, 0.3, (rows, cols))
    wide = seg.copy()
    wide[:, 0] = wide[:, -1] = n + 1
    a = segment_features(seg, n, xyz, height, valid, 0.3, True, 0, np.inf, np.inf, floor)
    b = segment_features(wide, n + 1, xyz, height, valid, 0.3, True, 0, np.inf, np.inf, floor)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y[: n + 1])


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_region_spacing_is_the_masked_median(seed):
    rng = np.random.default_rng(seed)
    rows, cols, n = int(rng.integers(2, 8)), int(rng.integers(1, 12)), int(rng.integers(1, 5))
    alt = np.radians(rng.permutation(np.linspace(-15.0, 5.0, rows)))
    ranges = rng.uniform(0.5, 40.0, (rows, cols)).astype(np.float32)
    scan = Scan(ranges, SpinningSensor.create(alt, cols))
    regions = rng.integers(0, n + 1, (rows, cols)).astype(np.int32)
    which = np.unique(rng.integers(1, n + 1, 2))
    # the numpy form: the slots of the wanted regions, range x the up gap as float32, their medians
    lab = regions.ravel()
    wanted = np.zeros(n + 1, bool)
    wanted[which] = True
    members = np.flatnonzero(wanted[lab])
    ref = np.zeros(n + 1)
    if len(members):
        spacing = ranges.ravel()[members].astype(np.float64) * beam_gap_up(alt)[members // cols]
        ids = lab[members].astype(np.int64)
        groups = np.unique(ids)
        ref[groups] = group_medians(ids, spacing.astype(np.float32), groups)
    np.testing.assert_array_equal(region_spacing(scan, regions, n, which), ref)


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_overlay_labels_is_the_masked_assignments(seed):
    """Sec. 8's order: ground (either mask), then curb, then vehicle where no curb is."""
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 6)), int(rng.integers(1, 9)))
    labels = rng.choice(np.array([0, 5, 68, 69], np.uint8), shape)
    ground, column, curb, car = (rng.random(shape) < 0.3 for _ in range(4))
    want = labels.copy()
    want[ground] = L.GROUND
    want[column] = L.GROUND
    want[curb] = L.CURB
    want[car & ~curb] = L.VEHICLE
    overlay_labels(labels, ground, column, curb, car)
    np.testing.assert_array_equal(labels, want)


def test_overlay_labels_hand_computed():
    labels = np.array([[68, 69, 5, 0]], np.uint8)
    yes, no = np.array([[True, True, True, False]]), np.zeros((1, 4), bool)
    overlay_labels(labels, yes, no, np.array([[False, True, False, False]]), np.array([[False, True, True, True]]))
    assert labels.tolist() == [[2, 66, 65, 65]]  # ground; curb over car; car over ground; car on no return
