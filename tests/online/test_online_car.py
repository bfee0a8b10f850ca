"""Car algorithm (Stamos et al., Sec. 7 and 8) on constructed profiler scan lines.

The block is a profiler (scan plane y-z, the paper's kind of vertical profile) driving past a
car parked on a flat road with a wall behind it: every scan line through the car crosses its
rounded side, its window (glass gives no return: the M state) and its roof.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam import labels as L
from prc_slam.online import OnlineDetector
from prc_slam.online.car import A_CAR, A_REGULAR, detect_cars, high_frequency_dominant, markov_cusum_trigger
from prc_slam.scan import ProfilerSensor, Scan, SpinningSensor

HEIGHT = 2.6  # scanner above the road
COLS = 2154
CAR_ROWS = range(50, 77)  # 27 lines x 0.17 m: a 4.6 m car
H, V, M = 0, 1, 2


def cast(segments: list[tuple], theta: np.ndarray) -> np.ndarray:
    """Range of the nearest segment hit by each beam ``(cos theta, sin theta)`` from the origin
    of the y-z plane; 0 (no return) beyond 60 m, in the sky, and where the hit is glass.
    ``segments``: ``(y0, z0, y1, z1, glass)``."""
    dy, dz = np.cos(theta), np.sin(theta)
    best = np.full(theta.shape, np.inf)
    glass = np.zeros(theta.shape, bool)
    for y0, z0, y1, z1, is_glass in segments:
        ey, ez = y1 - y0, z1 - z0
        det = -dy * ez + ey * dz
        ok = np.abs(det) > 1e-12
        safe = np.where(ok, det, 1.0)
        t = (-y0 * ez + ey * z0) / safe  # origin + t d = p0 + u e
        u = (dy * z0 - dz * y0) / safe
        hit = ok & (t > 0) & (u >= 0) & (u <= 1) & (t < best)
        best = np.where(hit, t, best)
        glass = np.where(hit, is_glass, glass)
    return np.where(np.isfinite(best) & ~glass & (best < 60), best, 0.0)


def street() -> list[tuple]:
    return [(-60.0, -HEIGHT, 60.0, -HEIGHT, False), (9.0, -HEIGHT, 9.0, 8.0 - HEIGHT, False)]


def car(y0: float = 3.0) -> list[tuple]:
    """Cross-section of a parked car, near side at ``y0``: rounded lower body from 0.3 m,
    shoulder at 0.95 m, window glass up to 1.4 m, roof, far side, underbody."""
    section = [
        (y0 + 0.1, 0.3, y0, 0.55, False),
        (y0, 0.55, y0 + 0.03, 0.9, False),
        (y0 + 0.03, 0.9, y0 + 0.15, 0.98, False),
        (y0 + 0.15, 0.98, y0 + 0.4, 1.4, True),  # side window
        (y0 + 0.4, 1.4, y0 + 1.4, 1.47, False),
        (y0 + 1.4, 1.47, y0 + 1.8, 1.4, False),
        (y0 + 1.8, 1.4, y0 + 1.8, 0.3, False),
        (y0 + 0.1, 0.3, y0 + 1.8, 0.3, False),
    ]
    return [(a, b - HEIGHT, c, d - HEIGHT, g) for a, b, c, d, g in section]


def bush(rng: np.random.Generator, y0: float = 3.0) -> list[tuple]:
    """A hedge of the car's size: 400 leaves (2 cm segments) scattered over 1.8 x 1.2 m."""
    centre = np.stack([rng.uniform(y0, y0 + 1.8, 400), rng.uniform(0.2, 1.4, 400) - HEIGHT], axis=1)
    angle = rng.uniform(0, np.pi, 400)
    half = 0.01 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    return [(*(c - h), *(c + h), False) for c, h in zip(centre, half, strict=True)]


def block(objects: list[tuple], rows: int = 120, noise: float = 0.005, seed: int = 0) -> Scan:
    """A profiler block: the street on every line, ``objects`` on the lines of ``CAR_ROWS``."""
    theta = 2 * np.pi * np.arange(COLS) / COLS
    r = np.tile(cast(street(), theta), (rows, 1))
    r[list(CAR_ROWS)] = cast(street() + objects, theta)
    rng = np.random.default_rng(seed)
    r = np.where(r > 0, r + rng.normal(0, noise, r.shape), 0.0)
    return Scan(r.astype(np.float32), ProfilerSensor.create(rows, COLS))


def on_object(scan: Scan) -> np.ndarray:
    xyz = scan.slot_xyz()
    box = (xyz[..., 1] > 2.9) & (xyz[..., 1] < 4.9) & (xyz[..., 2] > -HEIGHT + 0.15)
    rows = np.zeros(scan.shape, bool)
    rows[list(CAR_ROWS)] = True
    return scan.valid & box & rows


def test_markov_cusum_hand_computed():
    # H->H adds log(0.5/0.8) < 0 (W stays 0), H->V log(0.25/0.1) = 0.92 (below h = 1),
    # V->M log(0.25/0.01) = 3.22: the window dropout after the car's side triggers at index 3
    assert markov_cusum_trigger(np.array([H, H, V, M]), A_REGULAR, A_CAR, 1.0) == 3
    assert np.log(A_CAR[H, V] / A_REGULAR[H, V]) < 1.0
    assert markov_cusum_trigger(np.array([H, H, H, V, V, V]), A_REGULAR, A_CAR, 1.0) == -1  # road, then a wall
    assert markov_cusum_trigger(np.array([H, V, -1, M]), A_REGULAR, A_CAR, 1.0) == -1  # T' stops the detector


def test_fourier_test_hand_cases():
    step = np.r_[np.zeros(10), np.full(10, 90.0)]  # a car: side, then roof
    assert not high_frequency_dominant(step)  # energy at k = 0 and low k
    assert high_frequency_dominant(np.tile([60.0, -60.0], 10))  # sign flips every return: k = N/2
    assert not high_frequency_dominant(np.full(8, 45.0))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-180, 180), min_size=1, max_size=80))
def test_fourier_test_agrees_with_numpy(values):
    x = np.array(values)
    mags = np.abs(np.fft.rfft(x))
    band = mags[len(x) // 4 + 1 : len(x) // 2 + 1]
    margin = np.abs(band - mags.max() / 2).min() if len(band) else np.inf
    if margin > 1e-6 * max(mags.max(), 1.0):  # away from ties at the threshold
        assert high_frequency_dominant(x) == bool((band > mags.max() / 2).any())


def test_car_profile_with_window_dropouts():
    scan = block(car())
    truth = on_object(scan)
    theta = 2 * np.pi * np.arange(COLS) / COLS
    angle = np.arctan2(np.sin(theta), np.cos(theta))
    window = (angle > np.arctan2(0.98 - HEIGHT, 3.15)) & (angle < np.arctan2(1.4 - HEIGHT, 3.4))
    assert window.sum() > 20 and (scan.ranges[CAR_ROWS.start, window] == 0).all()  # glass: M states
    det = OnlineDetector()
    res = det.process(scan)
    assert abs(det.ground.height + HEIGHT) < 0.02
    vehicle = res.labels == L.VEHICLE
    assert truth.sum() > 2000
    assert vehicle[truth].mean() > 0.85  # side below the window and the roof
    assert not (vehicle & ~truth).any()  # nothing on the road or the wall
    assert not vehicle[: CAR_ROWS.start].any() and not vehicle[CAR_ROWS.stop :].any()
    # one instance across the window dropouts, boxed at the car's size
    assert len(res.car_boxes) == 1
    length, width, height = res.car_boxes[0]["size"]
    assert 4.2 < length < 4.8 and 1.6 < width < 2.0 and 1.0 < height < 1.25
    assert (res.car_instances[vehicle] == 1).all()


def test_a_hedge_of_the_same_size_is_not_a_car():
    scan = block(bush(np.random.default_rng(1)))
    truth = on_object(scan)
    res = OnlineDetector().process(scan)
    assert truth.sum() > 1000
    assert (res.labels[truth] == L.VEHICLE).mean() < 0.1


def test_cars_behind_a_verified_curb_keep_their_class():
    scan = block(car())
    det = OnlineDetector()
    res = det.process(scan)
    assert (res.labels == L.VEHICLE).any()
    # a verified curb return on the road in front of the car, on every line (Sec. 8)
    xyz = scan.slot_xyz()
    curb = scan.valid & (np.abs(xyz[..., 1] - 2.5) < 0.02) & (xyz[..., 2] < -HEIGHT + 0.05)
    assert curb[list(CAR_ROWS)].any(axis=1).all()
    cars = detect_cars(scan, res.coarse, det.ground.height, curb)
    assert not cars.mask.any() and cars.boxes == []


def test_bad_lines_give_no_cars():
    sensor = ProfilerSensor.create(3, 16)
    empty = Scan(np.zeros((3, 16), np.float32), sensor)
    det = OnlineDetector()
    res = det.process(empty)
    assert not (res.labels == L.VEHICLE).any() and res.car_boxes == []
    one = np.zeros((3, 16), np.float32)
    one[1, 3] = 4.0  # one return per block
    res = det.process(Scan(one, sensor))
    assert (res.labels[one == 0] == 0).all() and res.car_boxes == []
    nan = np.full((3, 16), np.nan, np.float32)
    res = det.process(Scan(nan, sensor))
    assert (res.labels == 0).all()
    # with a ground height but no returns at all
    from prc_slam.online.coarse import coarse_classify

    cars = detect_cars(empty, coarse_classify(empty), -2.6)
    assert not cars.mask.any() and cars.instances.shape == (3, 16)


def test_car_parked_at_a_curb_keeps_both():
    """A 12 cm curb at y = 5 m behind the car: the car stays a car (it is in front of the curb,
    Sec. 8), and the curb is found on the lines the car does not hide."""

    def kerbside() -> list[tuple]:
        top = 0.12 - HEIGHT
        return [(-60.0, -HEIGHT, 5.0, -HEIGHT, False), (5.0, -HEIGHT, 5.0, top, False), (5.0, top, 9.0, top, False)]

    theta = 2 * np.pi * np.arange(COLS) / COLS
    rows = 120
    r = np.tile(cast(kerbside(), theta), (rows, 1))
    r[list(CAR_ROWS)] = cast(kerbside() + car(2.95), theta)
    r = np.where(r > 0, r + np.random.default_rng(0).normal(0, 0.005, r.shape), 0.0)
    scan = Scan(r.astype(np.float32), ProfilerSensor.create(rows, COLS))
    xyz = scan.slot_xyz()
    face = scan.valid & (np.abs(xyz[..., 1] - 5.0) < 0.03) & (xyz[..., 2] > -HEIGHT + 0.005)
    res = OnlineDetector().process(scan)
    curb, vehicle = res.labels == L.CURB, res.labels == L.VEHICLE
    assert curb[face].mean() > 0.6 and (curb & ~face).sum() < 0.05 * curb.sum()
    assert not curb[list(CAR_ROWS)].any()  # hidden behind the car
    assert vehicle.sum() > 1500 and len(res.car_boxes) == 1


def test_per_line_ground_heights():
    from prc_slam.online.coarse import line_values, scan_lines

    scan = block(car())
    det = OnlineDetector()
    res = det.process(scan)
    n_lines = len(scan_lines(scan))
    assert det.ground.line_heights.shape == (n_lines,)
    assert np.abs(det.ground.line_heights + HEIGHT).max() < 0.03
    one = detect_cars(scan, res.coarse, det.ground.height).mask
    each = detect_cars(scan, res.coarse, np.full(n_lines, det.ground.height)).mask
    assert (one == each).all() and one.any()
    per_line = OnlineDetector(per_line_height=True).process(scan)
    assert (per_line.labels == L.VEHICLE)[on_object(scan)].mean() > 0.85
    with pytest.raises(ValueError, match="finite"):
        line_values(np.array([1.0, np.nan]), 2)
    with pytest.raises(ValueError):
        line_values(np.zeros(3), 2)  # one value per line, or one for all


def test_behind_bridged_curb_hand_computed():
    from prc_slam.online.car import behind_bridged_curb

    scan = Scan(np.zeros((5, 4), np.float32), ProfilerSensor.create(5, 4, line_spacing=0.25))
    # 5 up lines (rows 0-4, scanners at x = 0, 0.25, ..., 1.0), then 5 down lines; 2 slots each
    # (the lines' slots are made up: only their coordinates xy matter)
    lines = np.arange(20).reshape(10, 2)
    xy = np.zeros((20, 2))
    xy[:, 0] = np.repeat((np.arange(10) % 5) * 0.25, 2)
    xy[0::2, 1], xy[1::2, 1] = 4.0, 6.0  # each line: one return before y = 5, one after
    curb = np.full(10, -1)
    curb[0], curb[4] = 1, 9  # curb returns on rows 0 and 4 of the up lines: (0, 6) and (1, 6)
    behind = behind_bridged_curb(scan, lines, curb, xy, bridge=2.0)
    # the curb runs along y = 6 between them: nothing is beyond it on rows 1-3 ...
    assert not behind.any()
    xy[1::2, 1] = 7.0
    xy[1, 1] = xy[9, 1] = 5.0  # ... now it runs along y = 5, and rows 1-3 see y = 7 behind it
    behind = behind_bridged_curb(scan, lines, curb, xy, bridge=2.0)
    assert np.flatnonzero(behind).tolist() == [3, 5, 7]  # not the lines' own curbs, not the down lines
    assert not behind_bridged_curb(scan, lines, curb, xy, bridge=0.9).any()  # curb returns 1 m apart
    curb[4] = -1
    assert not behind_bridged_curb(scan, lines, curb, xy, bridge=2.0).any()  # no curb after the gap
    curb[4], curb[6] = -1, 13
    assert not behind_bridged_curb(scan, lines, curb, xy, bridge=2.0)[[3, 5, 7, 9]].any()  # other side
    curb[4], curb[6] = 9, -1
    assert behind_bridged_curb(scan, lines, curb, xy, bridge=2.0).any()
    sweep = Scan(np.zeros((2, 10), np.float32), SpinningSensor.create(np.radians([0.0, -5.0]), 10))
    assert not behind_bridged_curb(sweep, lines, curb, xy, bridge=2.0).any()  # profilers only


def test_lawn_behind_a_curb_hidden_by_a_parked_car():
    """Behind the curb at y = 5 m: a raised lawn (0.6 m) and a hedge. On the lines through the
    car the curb is hidden, and the lawn and hedge seen over the car joined the car's interval;
    the curb of the lines either side of the car sends them back (``CarParams.curb_bridge``)."""
    from prc_slam.online.car import CarParams

    def kerbside() -> list[tuple]:
        top, lawn = 0.12 - HEIGHT, 0.6 - HEIGHT
        return [
            (-60.0, -HEIGHT, 5.0, -HEIGHT, False),
            (5.0, -HEIGHT, 5.0, top, False),
            (5.0, top, 6.5, top, False),
            (6.5, top, 6.5, lawn, False),
            (6.5, lawn, 12.0, lawn, False),
            (12.0, lawn, 12.0, 8.0, False),
        ]

    theta = 2 * np.pi * np.arange(COLS) / COLS
    rows = 120
    r = np.tile(cast(kerbside(), theta), (rows, 1))
    r[list(CAR_ROWS)] = cast(kerbside() + car(2.95) + bush(np.random.default_rng(2), 9.0), theta)
    r = np.where(r > 0, r + np.random.default_rng(0).normal(0, 0.005, r.shape), 0.0)
    scan = Scan(r.astype(np.float32), ProfilerSensor.create(rows, COLS))
    xyz = scan.slot_xyz()
    beyond = scan.valid & (xyz[..., 1] > 5.05)
    body = on_object(scan)
    paper = OnlineDetector(car=CarParams(curb_bridge=0)).process(scan)
    res = OnlineDetector().process(scan)
    assert (paper.labels[beyond] == L.VEHICLE).sum() > 200  # the failure the bridge is for
    assert not (res.labels[beyond] == L.VEHICLE).any()
    assert (res.labels[body] == paper.labels[body]).all()  # the car in front of the curb keeps its labels
    assert (res.labels[body] == L.VEHICLE).mean() > 0.8 and len(res.car_boxes) == 1
