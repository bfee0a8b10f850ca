"""Online scan-line statistics and the coarse classifier (Stamos et al., Sec. 3, 4, 7.1)."""

from __future__ import annotations

import numpy as np
import pytest

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.online import CoarseParams, coarse_classify, scan_lines
from prc_slam.online import kernels as K
from prc_slam.online.coarse import shared_first
from prc_slam.scan import ProfilerSensor, Scan, SpinningSensor

P = CoarseParams()


def stats(points):
    xyz = np.asarray(points, float)
    return K.line_statistics(xyz, np.ones(len(xyz), bool), np.arange(len(xyz)), np.zeros(3))


def test_arccos_hand_computed():
    """The vectorising arccos at the ends and the reduction's seams (exact values)."""
    for c, deg in [(1.0, 0.0), (-1.0, 180.0), (0.0, 90.0)]:
        assert np.degrees(K.arccos(c)) == deg
    for c, deg in [(0.5, 60.0), (-0.5, 120.0), (np.sqrt(0.5), 45.0), (np.sqrt(3) / 2, 30.0), (-np.sqrt(3) / 2, 150.0)]:
        assert np.degrees(K.arccos(c)) == pytest.approx(deg, abs=1e-13)
    c = np.array([1.0, 0.5, -0.5, 0.0, -1.0, 0.25])
    K.arccos_into(c, 5)  # the first five only
    np.testing.assert_allclose(c, [0.0, 60.0, 120.0, 90.0, 180.0, 0.25], atol=1e-13)


def test_signed_angles_hand_computed():
    _, sv, _ = stats([[1, 0, 0], [2, 0, 0], [3, 0, 0]])
    np.testing.assert_allclose(sv, [90, 90, 90])  # horizontal: D perpendicular to z
    _, sv, _ = stats([[5, 0, 0], [5, 0, 1], [5, 0, 2]])
    np.testing.assert_allclose(sv, [0, 0, 0], atol=1e-9)  # vertical, rising
    _, sv, _ = stats([[1, 0, 0], [2, 0, 0.2], [1, 0, 0.4]])
    # D1 = (-1, 0, 0.2) turns back on D0 = (1, 0, 0.2): negative sign, V = acos(0.2 / |D1|)
    assert sv[1] == pytest.approx(-np.degrees(np.arccos(0.2 / np.sqrt(1.04))))


def test_line_angles_constant_on_collinear_points():
    # points of one straight line (a road seen by successive beams), not through the origin
    t = np.array([0.0, 0.7, 1.5, 2.6, 4.0])
    pts = np.stack([2 + t, np.zeros_like(t), -1.7 + 0.05 * t], axis=1)
    _, _, phi_hat = stats(pts)
    np.testing.assert_allclose(phi_hat, phi_hat[0], atol=1e-9)
    kinked = pts.copy()
    kinked[3:, 2] += [0.5, 1.2]
    assert np.ptp(stats(kinked)[2]) > 5


def test_min_step_forward_and_centred_hand_computed():
    # a road at z = 0, a 0.2 m step at x = 0.2 (points every 0.1 m), then the raised road
    pts = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.2, 0, 0.1], [0.2, 0, 0.2], [0.3, 0, 0.2], [0.4, 0, 0.2]])
    line = (pts, np.ones(len(pts), bool), np.arange(len(pts)), np.zeros(3))
    _, sv, _ = K.line_statistics(*line, 0.18, False)
    # forward: D_2 runs from X_2 to the first return >= 0.18 m away, X_4 = X_2 + (0, 0, 0.2): vertical
    assert sv[2] == pytest.approx(0.0, abs=1e-9)
    assert sv[1] == pytest.approx(np.degrees(np.arctan(0.5)))  # X_1 -> X_4 = (0.1, 0, 0.2): the road before
    _, sv, _ = K.line_statistics(*line, 0.18, True)
    # centred: D_k from >= 0.09 m before to >= 0.09 m after X_k
    assert sv[1] == pytest.approx(90.0)  # X_0 -> X_2, flat: the road stays horizontal
    assert sv[2] == pytest.approx(45.0)  # X_1 -> X_3 = (0.1, 0, 0.1)
    assert sv[3] == pytest.approx(0.0, abs=1e-9)  # X_2 -> X_4: the face itself is vertical
    _, paper, _ = K.line_statistics(*line, 0.0, True)
    _, plain, _ = K.line_statistics(*line)
    np.testing.assert_array_equal(paper, plain)  # min_step 0: the paper's successive differences


def test_hmm_cusum_first_llr_is_zero_and_detects_fast_switching():
    means = np.array(P.veg_means, float)
    steady = np.zeros(40)
    assert not K.hmm_cusum(steady, means, P.veg_sigma, P.veg_slow, P.veg_fast, P.veg_h).any()
    one = K.hmm_cusum(np.array([90.0]), means, P.veg_sigma, P.veg_slow, P.veg_fast, 0.0)
    assert not one[0]  # uniform priors: both models predict the same first sample, LLR = 0, W = 0
    rng = np.random.default_rng(0)
    veg = rng.choice([-90.0, 0.0, 90.0], 40)
    x = np.concatenate([steady, veg, steady + 90.0])
    out = K.hmm_cusum(x, means, P.veg_sigma, P.veg_slow, P.veg_fast, P.veg_h)
    assert not out[:40].any()
    assert out[45:80].mean() > 0.8  # detected within a few samples, back-dated to the change
    assert not out[-20:].any()  # and the return to regular surfaces


def test_mean_shift_cusum_hand_computed():
    # in H (mean 90): the LLR of x = 0 against V (mean 0) is (90^2 - 0^2) / (2 * 25^2) = 6.48 > 5
    out = K.mean_shift_cusum(np.array([90.0, 90.0, 0.0, 0.0, 0.0]), 90.0, 0.0, 25.0, 5.0)
    assert out.tolist() == [False, False, True, True, True]
    # a single 45 deg sample adds (45^2 - 45^2) / ... = 0: no switch
    assert not K.mean_shift_cusum(np.array([90.0, 45.0, 90.0]), 90.0, 0.0, 25.0, 5.0).any()


def column_scan(profile_z: np.ndarray, profile_x: np.ndarray) -> Scan:
    """A one-column 'spinning' scan whose beams hit the given (x, z) points."""
    el = np.arctan2(profile_z, profile_x)
    order = np.argsort(-el)  # row 0 = highest beam, as our sensors
    sensor = SpinningSensor.create(el[order], 1, azimuth0=-np.pi)  # column centre at azimuth 0
    r = np.hypot(profile_x, profile_z)[order]
    return Scan(r[:, None].astype(np.float32), sensor)


def test_road_then_wall_profile():
    x = np.concatenate([np.linspace(3, 12, 30), np.full(20, 12.0)])
    z = np.concatenate([np.full(30, -1.7), np.linspace(-1.5, 3, 20)])
    res = coarse_classify(column_scan(z, x))
    codes = res.codes[np.argsort(-np.arctan2(z, x))][:, 0]  # back to profile order
    assert (codes[:28] == L.HORIZONTAL).all()
    assert (codes[33:] == L.VERTICAL).all()


def test_tree_profile_is_vegetation():
    rng = np.random.default_rng(3)
    el = np.sort(rng.uniform(-0.2, 0.5, 60))
    r = 8 + rng.uniform(-1.2, 1.2, 60)  # a porous crown: range jumps back and forth
    x, z = r * np.cos(el), r * np.sin(el)
    res = coarse_classify(column_scan(z, x))
    assert (res.codes == L.VEGETATION).mean() > 0.7


def test_bad_lines_do_not_crash():
    sensor = SpinningSensor.create(np.radians([5.0, 0.0, -5.0]), 4)
    empty = coarse_classify(Scan(np.zeros((3, 4), np.float32), sensor))
    assert (empty.codes == 0).all()
    one = np.zeros((3, 4), np.float32)
    one[1, 2] = 7.0
    res = coarse_classify(Scan(one, sensor))
    assert res.codes[1, 2] in (L.HORIZONTAL, L.VERTICAL) and (res.codes[one == 0] == 0).all()
    nan = np.full((3, 4), np.nan, np.float32)
    assert (coarse_classify(Scan(nan, sensor)).codes == 0).all()


def test_profiler_lines_start_at_the_lowest_point():
    sensor = ProfilerSensor.create(2, 8)
    scan = Scan(np.full((2, 8), 5.0, np.float32), sensor)
    lines = scan_lines(scan)
    z = scan.slot_xyz()[..., 2].ravel()
    assert lines.shape == (4, 5)
    for line in lines:  # outwards from the lowest return...
        assert z[line[0]] == z.reshape(2, 8)[line[0] // 8].min()
    for up, down in zip(lines[:2], lines[2:], strict=True):  # ...in both directions
        assert up[0] == down[0] and (up[1] - up[0]) % 8 == 1 and (down[1] - down[0]) % 8 == 7
    used = lines[lines >= 0]
    assert sorted(set(used.tolist())) == list(range(16)) and len(used) == 16 + 2  # only the start is shared
    assert shared_first(scan) == 2


def test_profiler_lines_start_on_the_ground_near_the_scanner():
    """Ground: 2 m below the scanner up to y = 12 m, then 2 m lower: the lowest return of the
    line is far across the drop, but the line starts on the street (``start_radius`` 10 m)."""
    cols = 720
    theta = 2 * np.pi * np.arange(cols) / cols
    down = np.sin(theta) < -0.02
    t = np.where(down, -2.0 / np.where(down, np.sin(theta), -1.0), 0.0)
    far = down & (t * np.cos(theta) > 12.0)
    t[far] = -4.0 / np.sin(theta[far])
    t[t > 60] = 0.0
    scan = Scan(np.tile(t, (3, 1)).astype(np.float32), ProfilerSensor.create(3, cols))
    xyz = scan.slot_xyz().reshape(-1, 3)
    start = scan_lines(scan)[:, 0]
    assert np.allclose(xyz[start, 2], -2.0, atol=1e-4) and (np.hypot(xyz[start, 0], xyz[start, 1]) <= 10).all()
    assert np.allclose(xyz[scan_lines(scan, start_radius=np.inf)[:, 0], 2], -4.0, atol=1e-4)  # the lowest of all
    blind = np.where(np.abs(t * np.cos(theta)) <= 10.0, 0.0, t)  # no return near the scanner
    blind_scan = Scan(np.tile(blind, (3, 1)).astype(np.float32), ProfilerSensor.create(3, cols))
    xyz = blind_scan.slot_xyz().reshape(-1, 3)
    assert np.allclose(xyz[scan_lines(blind_scan)[:, 0], 2], -4.0, atol=1e-4)  # then the lowest of all


def test_simulated_frame(tmp_path):
    seq = open_dataset(write_sequence(Simulator(SimConfig(frames=1, seed=1)), tmp_path / "sim"))
    scan = seq[0]
    res = coarse_classify(scan)
    gt = scan.gt_labels
    assert ((res.codes > 0) == scan.valid).all()  # one code per return, none for missing slots
    assert (res.codes[gt == L.GROUND] == L.HORIZONTAL).mean() > 0.9
    assert (res.codes[gt == L.BUILDING] == L.VERTICAL).mean() > 0.75
    assert (res.codes[gt == L.TRUNK] == L.VERTICAL).mean() > 0.8
    assert (res.codes[gt == L.VEGETATION] == L.VEGETATION).mean() > (res.codes[gt == L.BUILDING] == L.VEGETATION).mean()


def line_returns_of(res, scan: Scan):
    """Check ``res.returns`` against its definition: each line's returns in order with their
    per-slot codes, line angles and heights."""
    z, valid = scan.slot_xyz64()[:, 2], scan.valid.ravel()
    codes, phi = res.codes.ravel(), res.phi_hat.ravel()
    for li, line in enumerate(res.lines):
        slots = np.array([s for s in line if s >= 0 and valid[s]], np.int64)
        m = res.returns.count[li]
        assert m == len(slots)
        np.testing.assert_array_equal(res.returns.pts[li, :m], slots)
        np.testing.assert_array_equal(res.returns.codes[li, :m], codes[slots])
        np.testing.assert_array_equal(res.returns.phi[li, :m], phi[slots].astype(np.float64))
        np.testing.assert_array_equal(res.returns.z[li, :m], z[slots])


@pytest.mark.parametrize("sensor", ["vlp16", "profiler-urban"])
def test_line_returns_are_the_lines_returns_with_their_slot_classes(sensor):
    """The rows the later stages read (a profiler's up lines share their first slot with a down
    line, whose classes it takes)."""
    sim = Simulator(SimConfig(frames=1, seed=2, sensor=sensor))
    scan = Scan(sim.frame(0).ranges, sim.sensor.model)
    scan.ranges[:, ::7] = 0.0  # slots without a return inside the lines
    line_returns_of(coarse_classify(scan), scan)
