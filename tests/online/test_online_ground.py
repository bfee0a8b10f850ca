"""Ground algorithm (Stamos et al., Sec. 5): mean shift, potential ground, dominant height."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.online import coarse_classify
from prc_slam.online.ground import GroundDetector, grow_single_mode, mean_shift_modes, single_mode
from prc_slam.scan import Scan, SpinningSensor


def test_mean_shift_modes_hand_cases():
    modes, counts = mean_shift_modes(np.array([0.0, 0.5, 1.0, 10.0, 10.4]), 2.0)
    np.testing.assert_allclose(modes, [0.5, 10.2])
    assert counts.tolist() == [3, 2]
    assert len(mean_shift_modes(np.array([1.0, 1.5, 2.2, 2.9, 3.6]), 2.0)[0]) == 1  # a chain is one mode


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-20, 20), min_size=1, max_size=40), st.floats(0.5, 5))
def test_single_mode_agrees_with_full_mean_shift(values, bandwidth):
    x = np.array(values)
    assert single_mode(x, bandwidth) == (len(mean_shift_modes(x, bandwidth)[0]) == 1)


def test_incremental_growth_on_a_sample_exactly_one_bandwidth_away():
    """Found by hypothesis: 1.0 and -8e-32 lie exactly one bandwidth apart in floating point
    (|z - m| <= h includes it) although m - h = 0.0 > -8e-32; both searches must agree."""
    x = np.array([1.0, -8.138075935518415e-32, -0.5])
    assert single_mode(x, 1.0)
    assert grow_single_mode(x, 0, 1, 3, 1.0) == 3


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-30, 30), min_size=3, max_size=60), st.integers(1, 10), st.floats(0.5, 8))
def test_incremental_growth_agrees_with_single_mode_on_every_prefix(values, first, bandwidth):
    x = np.array(values)
    first = min(first, len(x))
    expected = len(x)
    for e in range(first, len(x)):  # Sec. 5 (a), step 3: grow while one mode
        if not single_mode(x[: e + 1], bandwidth):
            expected = e
            break
    assert grow_single_mode(x, 0, first, len(x), bandwidth) == expected


def flat_street_scan(cols: int = 200, height: float = 1.7, wall: float | None = 14.0) -> Scan:
    """A spinning scan of a flat ground (z = -height) and, optionally, a wall at x = wall."""
    alt = np.radians(np.linspace(8, -24, 48))
    sensor = SpinningSensor.create(alt, cols)
    d = sensor.directions()
    t_ground = np.where(d[..., 2] < -1e-3, -height / np.minimum(d[..., 2], -1e-3), np.inf)
    r = t_ground
    if wall is not None:
        t_wall = np.where(np.abs(d[..., 0]) > 1e-3, wall / np.abs(d[..., 0]), np.inf)
        r = np.minimum(t_ground, t_wall)
    r = np.where(np.isfinite(r) & (r < 80), r, 0)
    rng = np.random.default_rng(0)
    r = np.where(r > 0, r + rng.normal(0, 0.005, r.shape), 0)
    return Scan(r.astype(np.float32), sensor)


def test_flat_ground_found_at_its_height_and_walls_are_not_ground():
    scan = flat_street_scan()
    det = GroundDetector()
    ground = det.process(scan, coarse_classify(scan))
    xyz = scan.slot_xyz()
    on_ground = scan.valid & (np.abs(xyz[..., 2] + 1.7) < 0.05)
    on_wall = scan.valid & (xyz[..., 2] > -1.5)
    assert abs(det.height + 1.7) < 0.03
    assert ground[on_ground].mean() > 0.8
    assert not ground[on_wall].any()
    # z_i per scan line (Sec. 5): one per line, every line of this street sees the road
    assert det.line_heights.shape == (scan.shape[1],)
    np.testing.assert_allclose(det.line_heights, -1.7, atol=0.03)


def test_ground_state_carries_over_frames_and_needs_50_estimates():
    det = GroundDetector()
    tiny = flat_street_scan(cols=20)
    assert not det.process(tiny, coarse_classify(tiny)).any()  # 20 lines: fewer than 50 estimates
    assert det.height is None
    more = flat_street_scan(cols=40)
    ground = det.process(more, coarse_classify(more))
    assert det.height is not None and ground.any()  # 60 estimates now, earlier lines re-run


def test_simulated_drive_ground_precision(tmp_path):
    seq = open_dataset(write_sequence(Simulator(SimConfig(frames=3, seed=2)), tmp_path / "sim"))
    det = GroundDetector()
    tp = fp = 0
    for scan in seq:
        g = det.process(scan, coarse_classify(scan))
        truth = np.isin(scan.gt_labels, [L.GROUND, L.CURB])
        tp += (g & truth).sum()
        fp += (g & ~truth).sum()
    assert tp / (tp + fp) > 0.95
    assert -1.9 < det.height < -1.5  # sensor 1.73 m above the road
