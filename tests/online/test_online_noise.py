"""The range noise of a sweep and the baseline it asks of the coarse classifier (``prc_slam.online.noise``),
and the two label rules built on it: steps over the baseline where the column spacing is under the noise
(``noise_labels``, ``SpinningCarParams.vegetation_noise``) and ring smoothness where the column does not
resolve the surface (``ring_labels``)."""

from __future__ import annotations

import numpy as np
import pytest

from prc_slam import labels as L
from prc_slam.online import OnlineDetector, SpinningCarParams
from prc_slam.online.noise import (
    MAD_TO_SIGMA,
    column_spacing,
    noise_baseline,
    noise_regime,
    range_noise,
    ring_surface,
)
from prc_slam.scan import Scan, SpinningSensor
from tests.inputs.spinning import car_boxes, ray_boxes


def test_range_noise_hand_computed():
    """Ranges alternating 10.00 / 10.01 m along a ring: every second difference is 0.02 m, so the
    noise is 1.4826 x 0.02 / sqrt(6); a 5 m jump (an edge) is left out rather than counted."""
    row = np.where(np.arange(400) % 2 == 0, 10.0, 10.01)
    row[200:] += 5.0  # one edge: the triples across it are not one surface
    got = range_noise(row[None, :])
    assert got == pytest.approx(MAD_TO_SIGMA * 0.02 / np.sqrt(6.0), rel=1e-9)
    assert np.isnan(range_noise(row[None, :50]))  # too few triples
    with pytest.raises(ValueError, match="range image"):
        range_noise(row)


def test_range_noise_of_a_noisy_ring_of_road():
    """A road ring (a circle around the sensor: constant range) with 3 cm of Gaussian noise."""
    rng = np.random.default_rng(1)
    ranges = 12.0 + rng.normal(0.0, 0.03, (8, 1024))
    assert range_noise(ranges) == pytest.approx(0.03, rel=0.1)


def test_noise_baseline_hand_computed():
    """sqrt(2) x 0.03 / tan(20 deg) = 0.11656 m; at 45 deg sqrt(2) x 0.03 = 0.04243 m; no noise, no baseline."""
    assert noise_baseline(0.03, 20.0) == pytest.approx(0.116565, abs=1e-6)
    assert noise_baseline(0.03, 45.0) == pytest.approx(0.042426, abs=1e-6)
    assert noise_baseline(float("nan"), 20.0) == 0.0
    with pytest.raises(ValueError, match="angle_sigma_deg"):
        noise_baseline(0.03, 90.0)


def test_column_spacing_and_noise_regime_hand_computed():
    """Beams at 3, 1 and 0 deg (rows given top first), all at 10 m: the 0 deg beam's next beam up is 1 deg
    away (0.1745 m), the 1 deg beam's 2 deg (0.349 m), the highest takes the gap below it (0.349 m)."""
    alt = np.radians([3.0, 1.0, 0.0])
    ranges = np.full((3, 2), 10.0)
    ranges[0, 1] = 0.0
    sp = column_spacing(ranges, alt)
    np.testing.assert_allclose(sp[:, 0], [10 * np.radians(2.0), 10 * np.radians(2.0), 10 * np.radians(1.0)])
    regime = noise_regime(ranges, alt, 0.2)
    assert regime[:, 0].tolist() == [False, False, True]
    assert not regime[0, 1]  # no return


def test_ring_surface_straight_vs_zigzag():
    """One ring over 1024 columns (6.1 mm a column at 1 m): returns on a straight wall turn by nothing; returns
    alternating 0.5 m in depth turn by far more than 45 deg; steps longer than three times the column
    spacing (an edge) are no surface."""
    cols = 1024
    step = 2.0 * np.pi / cols * 10.0  # 6.1 cm at 10 m
    x = np.full(cols, 10.0)
    y = np.arange(cols) * step
    xyz = np.stack([x, y, np.zeros(cols)], axis=1)[None]
    ranges = np.full((1, cols), 10.0)
    valid = np.ones((1, cols), bool)
    flat = ring_surface(xyz, valid, ranges, 0.05, 45.0)
    assert flat[0, 1:-1].all()  # the wrap-around ends jump across the whole ring
    zig = xyz.copy()
    zig[0, ::2, 0] += 0.05
    assert not ring_surface(zig, valid, ranges, 0.05, 45.0)[0, 1:-1].any()
    only = np.zeros((1, cols), bool)
    only[0, 10] = True
    assert ring_surface(xyz, valid, ranges, 0.05, 45.0, at=only).sum() == 1
    picked = ring_surface(xyz, valid, ranges, 0.05, 45.0, at=(np.array([0, 0]), np.array([10, 20])))
    assert np.flatnonzero(picked[0]).tolist() == [10, 20]


def _near_car_sweep(noise: float, seed: int = 0) -> tuple[Scan, np.ndarray]:
    """An OS0-128-like layout (128 beams over +-45 deg, 1024 columns, 1.73 m up) with a car 1.5 m beside it."""
    model = SpinningSensor.create(np.radians(np.linspace(45.0, -45.0, 128)), 1024)
    ranges, ident = ray_boxes(model.directions(), car_boxes(-2.0, 1.5))
    glass = ident < 0
    ranges[glass], ident[glass] = 0.0, 0
    rng = np.random.default_rng(seed)
    ranges = np.where(ranges > 0, ranges + rng.normal(0.0, noise, ranges.shape), 0.0).astype(np.float32)
    return Scan(ranges, model), ident


def test_a_car_beside_a_fine_beam_sensor_is_no_vegetation():
    """A car body 1.5-3 m from an OS0-128-like sensor has its column returns 2-4 cm apart, under its 3 cm of
    range noise: the paper's successive steps call much of it vegetation, and step 6 rejects the car. Over
    the noise baseline (0.117 m) its returns are a surface and the car is found."""
    scan, ident = _near_car_sweep(0.03)
    car = ident == 1
    old = OnlineDetector(noise_labels=False, ring_labels=False, spinning=SpinningCarParams(vegetation_noise=False))
    new = OnlineDetector()
    for det in (old, new):
        det.process(scan)
    lab_old, lab_new = old.process(scan).labels, new.process(scan).labels
    assert new.range_sigma(scan) == pytest.approx(0.03, rel=0.2)
    assert (lab_old[car] == L.VEGETATION).mean() > 0.2
    assert (lab_new[car] == L.VEHICLE).mean() > 0.8
    assert (lab_new[car] == L.VEGETATION).mean() < 0.05


def test_coarse_classify_on_some_lines_only():
    """``coarse_classify(only=...)`` classifies the chosen columns as the full run does and leaves the others 0."""
    from prc_slam.online.coarse import coarse_classify

    scan, _ = _near_car_sweep(0.03)
    full = coarse_classify(scan, t_prime=False)
    only = np.zeros(len(full.lines), bool)
    only[::7] = True
    part = coarse_classify(scan, t_prime=False, only=only)
    chosen = np.zeros(scan.shape[0] * scan.shape[1], bool)
    chosen[full.lines[only].ravel()] = True
    chosen = chosen.reshape(scan.shape)
    np.testing.assert_array_equal(part.codes[chosen], full.codes[chosen])
    assert (part.codes[~chosen] == 0).all() and (full.codes[~chosen & scan.valid] > 0).all()
    with pytest.raises(ValueError, match="one flag per scan line"):
        coarse_classify(scan, only=only[:-1])


def test_ring_surface_skips_missing_returns():
    """A straight wall with every second return missing (dark paint): the nearest returns two columns away
    each side still make one surface; with nothing within ``max_offset`` columns there is no test."""
    cols = 1024
    step = 2.0 * np.pi / cols * 10.0
    xyz = np.stack([np.full(cols, 10.0), np.arange(cols) * step, np.zeros(cols)], axis=1)[None]
    ranges = np.full((1, cols), 10.0)
    valid = np.ones((1, cols), bool)
    valid[0, 1::2] = False
    got = ring_surface(xyz, valid, ranges, 0.05, 45.0)
    assert got[0, 2:-2:2].all() and not got[0, 1::2].any()
    sparse = np.zeros((1, cols), bool)
    sparse[0, ::8] = True
    assert not ring_surface(xyz, sparse, ranges, 0.05, 45.0, max_offset=4).any()


def test_roof_allowance_across_beams_that_returned_nothing():
    """Beams at -0.2, -0.1, -0.05, +0.05 rad, 2 m up, farthest return 30 m: the -0.1 rad beam meets the ground
    19.9 m out and must have met something, the -0.05 rad beam only 40 m out (beyond the sweep's range) and the
    +0.05 rad beam never. Above a return on the lowest beam, a miss on the -0.1 rad beam stretches the gap to the
    next return (0.15 rad); a miss on the -0.05 rad beam too leaves the plain gap (0.1 rad)."""
    from prc_slam.online.spinning import missing_top_gaps

    alt = np.array([-0.2, -0.1, -0.05, 0.05])
    gaps = np.array([0.1, 0.05, 0.1, 0.0])
    valid = np.array([[1, 1, 1], [0, 0, 1], [1, 0, 1], [1, 1, 1]], bool)
    out = missing_top_gaps(valid, alt, gaps, 2.0, 30.0)
    np.testing.assert_allclose(out[0], [0.15, 0.1, 0.1])
    np.testing.assert_allclose(out[3], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="one value per row"):
        missing_top_gaps(valid, alt[:3], gaps, 2.0, 30.0)
