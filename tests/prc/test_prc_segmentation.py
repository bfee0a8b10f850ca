"""Connected components, hole filling, dilation, boundary voting, smooth/nonsmooth split,
classification (Sec. II-D to II-F), and the streaming invariants."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data_tools.synthetic import profiler_block
from prc_slam import labels as L
from prc_slam.config import PRCConfig
from prc_slam.prc import PRCState, PRCStream, column_density_ground, kernels, prc_block
from prc_slam.prc.algorithm import boundary_relabel
from prc_slam.scan import ProfilerSensor


def test_components_are_four_connected():
    m = np.array([[1, 1, 0, 0], [0, 1, 0, 1], [0, 0, 1, 1]], dtype=bool)
    lab, n = kernels.connected_components(m, False)
    assert n == 2  # (1,1) and (2,2) touch only diagonally
    assert lab[0, 0] == lab[0, 1] == lab[1, 1] == 1
    assert lab[1, 3] == lab[2, 2] == lab[2, 3] == 2
    assert (lab[~m] == 0).all()


def test_components_u_shape_merges_and_wraps():
    m = np.array([[1, 0, 1], [1, 0, 1], [1, 1, 1]], dtype=bool)
    assert kernels.connected_components(m, False)[1] == 1
    m2 = np.array([[1, 0, 0, 1]], dtype=bool)
    assert kernels.connected_components(m2, False)[1] == 2
    assert kernels.connected_components(m2, True)[1] == 1


@settings(max_examples=80, deadline=None)
@given(
    st.integers(1, 9).flatmap(
        lambda rows: st.integers(1, 40).flatmap(
            lambda cols: st.lists(st.booleans(), min_size=rows * cols, max_size=rows * cols).map(
                lambda v: np.array(v, bool).reshape(rows, cols)
            )
        )
    ),
    st.booleans(),
)
def test_components_by_runs_equal_pixelwise_union_find(m, wrap):
    """The run-based labelling gives the pixel-wise one's labels exactly (raster order of
    each component's first pixel), with and without the wrap."""
    lab, n = kernels.connected_components(m, wrap)
    ref, n_ref = kernels.connected_components_within(m, np.zeros((1, 1, 3)), np.inf, wrap)
    assert n == n_ref
    np.testing.assert_array_equal(lab, ref)


def test_hole_filling_takes_most_common_label_of_8_neighbourhood():
    lab = np.array([[1, 1, 2], [2, 0, 2], [0, 2, 0]], dtype=np.int32)
    holes = np.zeros_like(lab, bool)
    holes[1, 1] = True
    out = kernels.fill_holes(lab, holes, False)
    assert out[1, 1] == 2  # 2 appears four times, 1 twice
    # tie: smaller label wins
    lab2 = np.array([[3, 3, 0], [0, 0, 0], [5, 5, 0]], dtype=np.int32)
    holes2 = np.zeros_like(lab2, bool)
    holes2[1, 1] = True
    assert kernels.fill_holes(lab2, holes2, False)[1, 1] == 3
    # no labelled neighbour: stays 0; input not modified
    lab3 = np.zeros((3, 3), np.int32)
    assert kernels.fill_holes(lab3, holes2, False)[1, 1] == 0
    assert lab[1, 1] == 0


def test_hole_filling_reads_the_unfilled_image():
    # two adjacent holes: each sees only the original labels, never the other's fill
    lab = np.array([[7, 0, 0, 9]], dtype=np.int32)
    holes = np.array([[False, True, True, False]])
    out = kernels.fill_holes(lab, holes, False)
    assert out.tolist() == [[7, 7, 9, 9]]


def test_dilation_four_neighbourhood():
    m = np.zeros((5, 5), bool)
    m[2, 2] = True
    d1 = kernels.dilate4(m, 1, False)
    assert d1.sum() == 5 and not d1[1, 1]
    d2 = kernels.dilate4(m, 2, False)
    assert d2.sum() == 13  # diamond of radius 2
    assert not m[1, 2]  # input untouched


def test_boundary_vote_needs_three_votes_and_picks_the_majority():
    first = np.array([1, 1, 1, 1, 2, 2, 3, 3, 3, 0])
    prev = np.array([10, 10, 10, 11, 12, 12, 0, 0, 0, 13])
    m = boundary_relabel(first, prev, 3)
    assert m == {1: 10}  # segment 2 has only 2 votes; zeros never vote
    # a fork: two segments of H_b voted for the same label both inherit it
    first2 = np.array([1, 1, 1, 0, 2, 2, 2])
    prev2 = np.array([10, 10, 10, 10, 10, 10, 10])
    assert boundary_relabel(first2, prev2, 3) == {1: 10, 2: 10}


def _flat_blocks(k: int, M: int, n_blocks: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (10.0 + rng.normal(0, 0.002, (k * n_blocks, M))).astype(np.float32)


def test_continuous_blocks_keep_segment_ids_across_the_boundary():
    cfg = PRCConfig(k=10, A=30)
    sensor = ProfilerSensor.create(10, 40)
    stream = PRCStream(cfg, sensor)
    blocks = stream.push(_flat_blocks(10, 40, 3))
    ids = [np.unique(b.segments[b.segments > 0]) for b in blocks]
    assert all(len(i) == 1 for i in ids)
    assert ids[0][0] == ids[1][0] == ids[2][0]
    assert all((b.labels == L.GROUND).all() for b in blocks)  # one smooth patch: the ground
    # without the carried state every block gets fresh ids
    fresh = [prc_block(b, cfg) for b in np.split(_flat_blocks(10, 40, 2), 2)]
    assert fresh[0].segments.max() == fresh[1].segments.max() == 1


def test_smooth_nonsmooth_split_by_area():
    # a big flat wall (smooth) and scattered 2x2 patches (nonsmooth) in a noise background
    rng = np.random.default_rng(1)
    r = rng.uniform(1, 100, (20, 60)).astype(np.float32)
    r[2:18, 2:30] = 10.0
    for c in range(35, 58, 6):
        r[5:8, c : c + 4] = 20.0 + c
    cfg = PRCConfig(A=30, gamma=0, xi_s=0.5, xi_p=0.5)
    res = prc_block(r, cfg)
    assert res.smooth[5:15, 5:27].all()
    assert (res.labels[5:15, 5:27] == L.GROUND).all()  # largest smooth patch
    small = res.labels[6, 36:39]
    assert (small == L.VEGETATION).all()
    assert not res.smooth[6, 36:39].any()


def test_gamma_dilation_joins_nearby_small_patches():
    r = np.full((12, 40), 0.0, dtype=np.float32)
    r[4:8, 5:9] = 12.0
    r[4:8, 11:15] = 12.0  # two patches two columns apart
    base = PRCConfig(A=30, xi_s=0.5, xi_p=0.5)
    apart = prc_block(r, base.model_copy(update={"gamma": 0}))
    joined = prc_block(r, base.model_copy(update={"gamma": 2}))
    assert apart.segments[5, 6] != apart.segments[5, 12]
    assert joined.segments[5, 6] == joined.segments[5, 12]


def test_forest_column_density_eq12():
    smooth = np.zeros((9, 25), bool)
    smooth[:4, 0] = True  # column 0: 4/9 > 1/3 -> columns 0..9 ground
    smooth[:3, 10] = True  # column 10: 3/9 = 1/3, not > 1/3
    smooth[:, 11] = True  # not evaluated (only every 10th column)
    smooth[:9, 20] = True  # columns 20..24
    g = column_density_ground(smooth, PRCConfig(mode="forest"))
    assert g[:, :10].all() and not g[:, 10:20].any() and g[:, 20:].all()


def test_forest_mode_classes():
    block = profiler_block(60, 400, seed=3)
    res = prc_block(block.ranges, PRCConfig.preset("forest", k=60))
    assert set(np.unique(res.labels)) <= {L.NO_RETURN, L.UNCLASSIFIED, L.NOISE, L.GROUND, L.TRUNK, L.VEGETATION}


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 70), min_size=1, max_size=12), st.integers(0, 5))
def test_stream_chunking_invariance(chunks, seed):
    block = profiler_block(150, 120, seed=seed, street_half_width=4.0)
    cfg = PRCConfig(k=33)
    sensor = ProfilerSensor.create(33, 120)
    ref_stream = PRCStream(cfg, sensor)
    ref = np.concatenate([b.labels for b in ref_stream.push(block.ranges) + ref_stream.flush()])
    stream = PRCStream(cfg, sensor)
    out, start = [], 0
    for n in chunks:
        out += stream.push(block.ranges[start : start + n])
        start += n
        if start >= 150:
            break
    out += stream.push(block.ranges[start:]) if start < 150 else []
    out += stream.flush()
    got = np.concatenate([b.labels for b in out])
    np.testing.assert_array_equal(got, ref)
    assert got.shape == block.ranges.shape  # one label per input slot


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 40), st.integers(1, 60), st.integers(0, 10**6), st.sampled_from(["urban", "forest"]))
def test_one_label_per_slot_and_no_return_is_zero(rows, cols, seed, mode):
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.5, 50, (rows, cols)).astype(np.float32)
    r[rng.random((rows, cols)) < 0.2] = 0.0
    res = prc_block(r, PRCConfig.preset(mode), state=PRCState())
    assert res.labels.shape == r.shape and res.labels.dtype == np.uint8
    assert ((res.labels == L.NO_RETURN) == (r == 0)).all()
    assert ((res.labels == L.NOISE) == ((r > 0) & ~res.supported)).all()
    assert (res.segments[~res.supported] == 0).all()


def test_prc_block_does_not_modify_input():
    block = profiler_block(40, 300, seed=2)
    before = block.ranges.copy()
    prc_block(block.ranges, PRCConfig())
    np.testing.assert_array_equal(block.ranges, before)


def test_stream_rejects_bad_lines():
    stream = PRCStream(PRCConfig(k=5), ProfilerSensor.create(5, 10))
    with pytest.raises(ValueError, match="shape"):
        stream.push(np.zeros((2, 11), np.float32))
    with pytest.raises(ValueError, match="infinite or negative"):
        stream.push(np.full((2, 10), np.inf, np.float32))
    assert stream.push(np.full((2, 10), np.nan, np.float32)) == []  # NaN is 'no return'
    assert (stream.flush()[0].labels == L.NO_RETURN).all()


def test_paper_urban_classes_on_simulated_street():
    scan = profiler_block(99, 2154, seed=0)
    res = prc_block(scan.ranges, PRCConfig.preset("urban"))
    gt = scan.gt_labels
    noise = gt == L.NOISE
    assert (res.labels[noise] == L.NOISE).mean() > 0.9  # background-illumination outliers
    bld = gt == L.BUILDING
    assert (res.labels[bld] == L.BUILDING).mean() > 0.6


def test_forest_ring_density_for_spinning_sensors():
    smooth = np.zeros((3, 20), bool)
    smooth[0, :8] = True  # ring 0: 8/20 = 0.4 > 1/3 -> ground
    smooth[1, :6] = True  # ring 1: 6/20 = 0.3 -> not
    smooth[2, 10:14] = True  # ring 2, window of 10: 4/10 in the second window -> ground there only
    cfg = PRCConfig(mode="forest", density_window=20)
    g = column_density_ground(smooth, cfg, axis="rows")
    assert g[0].all() and not g[1].any()
    g10 = column_density_ground(smooth, PRCConfig(mode="forest", density_window=10), axis="rows")
    assert not g10[2, :10].any() and g10[2, 10:].all()
    # a last, shorter window is normalised by its own length
    g7 = column_density_ground(smooth[:, :14], PRCConfig(mode="forest", density_window=7), axis="rows")
    assert g7[2, 7:14].all()  # ring 2, columns 7..13: 4 of 7 smooth


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.booleans(), st.integers(1, 7), st.integers(1, 40))
def test_fused_kernels_equal_the_step_kernels(seed, wrap, rows, cols):
    """fill_holes_sized = fill_holes + bincount; combine_codes = combine + class_codes."""
    rng = np.random.default_rng(seed)
    fg = rng.random((rows, cols)) < 0.5
    holes = ~fg & (rng.random((rows, cols)) < 0.6)
    lab, n = kernels.connected_components(fg, wrap)
    filled, size = kernels.fill_holes_sized(lab, holes, wrap, n)
    assert np.array_equal(filled, kernels.fill_holes(lab, holes, wrap))
    assert np.array_equal(size, np.bincount(filled.ravel(), minlength=n + 1))
    ranges = (rng.random((rows, cols)) < 0.9) * rng.uniform(1, 50, (rows, cols)).astype(np.float32)
    supported = (ranges > 0) & (rng.random((rows, cols)) < 0.8)
    smooth_lut = rng.random(n + 1) < 0.5
    smooth_lut[0] = False
    smooth, small = kernels.split_smooth(filled, smooth_lut)
    dilated = kernels.dilate4(small, 2, wrap)
    v_local, _ = kernels.connected_components(dilated, wrap)
    glob = (np.arange(n + 1) + 5).astype(np.int32)
    glob[0] = 0
    seg, nonsmooth = kernels.combine(filled, glob, smooth, small, dilated, v_local, 100, supported)
    ground = int(rng.choice(glob)) if n else 0
    codes = kernels.class_codes(ranges, supported, smooth, nonsmooth, seg, ground, 3, 4, 5, 6, 7)
    seg2, nonsmooth2, codes2 = kernels.combine_codes(
        ranges, filled, glob, smooth, small, dilated, v_local, 100, supported, ground, 3, 4, 5, 6, 7
    )
    assert np.array_equal(seg, seg2) and np.array_equal(nonsmooth, nonsmooth2) and np.array_equal(codes, codes2)
