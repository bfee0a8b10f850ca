"""Scan / SensorModel data model, label mappings, and classification scores."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam import labels as L
from prc_slam.evaluation.metrics import ConfusionAccumulator
from prc_slam.scan import ProfilerSensor, Scan, ScanError, SpinningSensor, sensor_from_description


def test_scan_normalises_nan_and_rejects_inf():
    sensor = ProfilerSensor.create(2, 3)
    r = np.array([[1.0, np.nan, 2.0], [0.0, 3.0, 4.0]])
    s = Scan(r, sensor, source="x.bin")
    assert s.ranges[0, 1] == 0.0 and s.meta["nan_ranges"] == 1
    assert s.n_points == 4
    assert Scan(np.ones((2, 3)), sensor).meta["nan_ranges"] == 0
    with pytest.raises(ScanError, match=r"1 infinite"):  # -inf: below every range, caught too
        Scan(np.array([[1.0, -np.inf, np.nan], [1, 1, 1]]), sensor)
    with pytest.raises(ScanError, match=r"x.bin: 1 infinite"):
        Scan(np.array([[1.0, np.inf, 2.0], [1, 1, 1]]), sensor, source="x.bin")
    with pytest.raises(ScanError, match="negative"):
        Scan(np.array([[1.0, -1, 2.0], [1, 1, 1]]), sensor)
    with pytest.raises(ScanError, match="does not match the sensor"):
        Scan(np.ones((3, 3)), sensor)
    with pytest.raises(ScanError, match="gt_labels shape"):
        Scan(np.ones((2, 3)), sensor, gt_labels=np.zeros((3, 2), np.uint8))


@settings(max_examples=30, deadline=None)
@given(
    rows=st.integers(1, 5),
    cols=st.integers(1, 9),
    seed=st.integers(0, 2**32 - 1),
    order=st.sampled_from(["C", "F", "reversed"]),
)
def test_to_xyz_kernel_is_the_broadcast_product(rows, cols, seed, order):
    """``to_xyz``'s one-pass kernel gives numpy's ``unit_rays * ranges[..., None]`` bit for bit (float32
    products; zeros stay zeros), for any memory layout of the ranges; a wrong shape is refused."""
    rng = np.random.default_rng(seed)
    sensor = SpinningSensor.create(np.sort(rng.uniform(-0.4, 0.2, rows)), cols)
    ranges = (rng.uniform(0.0, 120.0, (rows, cols)) * (rng.random((rows, cols)) > 0.2)).astype(np.float32)
    if order == "F":
        ranges = np.asfortranarray(ranges)
    elif order == "reversed":
        ranges = ranges[::-1]
    xyz = sensor.to_xyz(ranges)
    expected = sensor.unit_rays * np.asarray(ranges, dtype=np.float32)[..., None]
    assert xyz.dtype == np.float32 and xyz.shape == (rows, cols, 3) and xyz.flags.c_contiguous
    assert xyz.tobytes() == expected.tobytes()
    assert (xyz[ranges == 0] == 0).all()
    with pytest.raises(ScanError, match="does not match sensor"):
        sensor.to_xyz(np.ones((rows + 1, cols)))


def test_to_xyz_kernel_hand_computed():
    """One beam at 0 elevation, four columns (azimuths 45, 135, 225, 315 deg): range 2 lands at
    2 (cos, sin, 0) of the azimuth; range 0 at the origin."""
    sensor = SpinningSensor.create(np.radians([0.0]), 4)
    xyz = sensor.to_xyz(np.array([[2.0, 0.0, 2.0, 2.0]]))
    h = np.float32(np.sqrt(2.0))
    np.testing.assert_allclose(xyz[0], [[h, h, 0], [0, 0, 0], [-h, -h, 0], [h, -h, 0]], atol=1e-6)


def test_spinning_directions_hand_computed():
    s = SpinningSensor.create(np.radians([0.0, 30.0]), 4)
    xyz = s.to_xyz(np.full((2, 4), 2.0))
    # column 0 centre at azimuth 2*pi*0.5/4 = 45 deg
    np.testing.assert_allclose(xyz[0, 0], [np.sqrt(2), np.sqrt(2), 0.0], atol=1e-6)
    np.testing.assert_allclose(
        xyz[1, 2],
        [
            2 * np.cos(np.radians(30)) * np.cos(np.radians(225)),
            2 * np.cos(np.radians(30)) * np.sin(np.radians(225)),
            1.0,
        ],
        atol=1e-6,
    )
    assert sensor_from_description(s.describe()).describe() == s.describe()


def test_profiler_directions_and_mount():
    tilt = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)  # 90 deg about x
    p = ProfilerSensor.create(1, 4, mount=tilt)
    xyz = p.to_xyz(np.ones((1, 4)))
    np.testing.assert_allclose(xyz[0, 0], [0, 0, 1], atol=1e-6)  # +y rotated to +z
    np.testing.assert_allclose(xyz[0, 1], [0, -1, 0], atol=1e-6)  # +z rotated to -y
    assert p.continuous_rows
    assert sensor_from_description(p.describe()).describe() == p.describe()


def test_per_point_with_shared_slots():
    sensor = SpinningSensor.create(np.zeros(1), 3)
    cloud = np.zeros((4, 3), np.float32)
    s = Scan(np.array([[1.0, 0, 2.0]]), sensor, cloud=cloud, point_slot=np.array([2, 0, 2, 0]))
    assert s.per_point(np.array([[5, 6, 7]])).tolist() == [7, 5, 7, 5]
    with pytest.raises(ScanError, match="point_slot indexes outside"):
        Scan(np.array([[1.0, 0, 2.0]]), sensor, cloud=cloud, point_slot=np.array([3, 0, 2, 0]))


def test_semantic_kitti_mapping():
    raw = np.array([40, 48, 50 | (3 << 16), 70, 71, 10, 252, 80, 1, 99, 0], dtype=np.uint32)
    assert L.from_semantic_kitti(raw).tolist() == [
        L.GROUND,
        L.GROUND,
        L.BUILDING,
        L.VEGETATION,
        L.TRUNK,
        L.VEHICLE,
        L.VEHICLE,
        L.POLE,
        L.NOISE,
        L.UNCLASSIFIED,
        L.UNCLASSIFIED,
    ]
    assert L.instances_from_semantic_kitti(raw)[2] == 3
    assert L.to_label_file(np.array([2, 65], np.uint8)).dtype == np.uint32


def test_confusion_hand_computed():
    acc = ConfusionAccumulator()
    ref = np.array([2, 2, 2, 2, 6, 6, 7, 0])
    pred = np.array([2, 2, 2, 7, 6, 2, 7, 2])
    acc.add(ref, pred)
    g = acc.scores(L.GROUND)
    assert g["support"] == 4 and g["recall"] == pytest.approx(0.75) and g["precision"] == pytest.approx(0.75)
    n = acc.scores(L.NOISE)
    assert n["precision"] == pytest.approx(0.5) and n["recall"] == 1.0
    assert n["f1"] == pytest.approx(2 * 0.5 / 1.5)
    assert acc.fraction([L.GROUND, L.BUILDING], L.NOISE) == pytest.approx(1 / 6)
    js = acc.to_json()
    assert js["labels"] == ["ground", "building", "noise"]
    np.testing.assert_allclose(js["matrix"][0], [0.75, 0.0, 0.25])
    with pytest.raises(ValueError, match="reference labels for"):
        acc.add(ref, pred[:3])


@settings(max_examples=40, deadline=None)
@given(
    rows=st.integers(1, 128),
    cols=st.integers(2, 4096),
    seed=st.integers(0, 2**32 - 1),
    azimuth0=st.floats(-7.0, 7.0),
    direction=st.sampled_from([-1, 1]),
)
def test_unit_rays_from_angle_sums_equal_the_directions(rows, cols, seed, azimuth0, direction):
    rng = np.random.default_rng(seed)
    sensor = SpinningSensor.create(
        rng.uniform(-1.5, 1.5, rows),
        cols,
        beam_azimuth=rng.uniform(-0.2, 0.2, rows),
        column_shift=rng.integers(-32, 32, rows).astype(float),
        azimuth0=azimuth0,
        direction=direction,
    )
    rays = sensor.unit_rays
    assert rays.dtype == np.float32 and rays.shape == (rows, cols, 3)
    np.testing.assert_allclose(rays, sensor.directions(), rtol=0, atol=1e-7)  # float32's rounding
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-6)
