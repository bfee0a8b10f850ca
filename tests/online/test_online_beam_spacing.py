"""Curb and car tests of spinning sensors scaled by the beam spacing at the return's range.

Hand-computed cases: a single column crossing a 12 cm curb (beams 1 deg apart, sensor 2 m above
level ground), the expected ground run of two beams, the vertical beam spacing of Sec. 6's regions,
and a car whose lower body lies between two beams of a 32-beam sensor.
"""

from __future__ import annotations

import numpy as np

from prc_slam import labels as L
from prc_slam.online import OnlineDetector
from prc_slam.online.curb import beam_gap_up, region_spacing
from prc_slam.online.spinning import SpinningCarParams, _curb_faces, _ground_run
from prc_slam.scan import Scan, SpinningSensor
from tests.inputs.spinning import MOUNT, car_boxes, sweep

#: beams of the hand-made column (deg), lowest first; one column, so a slot's row is its index
ALT = np.radians([-12.0, -11.0, -10.0, -9.0, -8.0])


def column(z: list[float]) -> np.ndarray:
    """Returns of the column at heights ``z`` (sensor at the origin), each where its beam reaches that height."""
    z = np.asarray(z, dtype=np.float64)
    rho = -z / np.tan(-ALT)
    return np.column_stack([rho, np.zeros_like(rho), z])


def faces(xyz: np.ndarray, relative: bool, min_step: float = 0.02) -> np.ndarray:
    n = len(xyz)
    return _curb_faces(
        xyz, np.ones(n, bool), np.arange(n)[None, :], np.full(n, -2.0), 0.5, 0.1, 0.05, 0.2, 0.05, ALT, 1,
        relative, 0.02, min_step if relative else 0.0, 0.4,
    )  # fmt: skip


def test_ground_run_of_two_beams_hand_computed():
    # 2 m below the sensor, beams at -10 and -9 deg meet the ground at 2 cot 10 = 11.343 and 2 cot 9 = 12.627 m
    assert abs(_ground_run(-2.0, np.radians(-10.0), np.radians(-9.0)) - 1.2851) < 1e-3
    assert _ground_run(-2.0, np.radians(-1.0), np.radians(1.0)) == 0.0  # the upper beam never meets the ground
    assert _ground_run(2.0, np.radians(-10.0), np.radians(-9.0)) == 0.0  # ground above the sensor: no run


def test_curb_face_within_one_beam_gap_is_found_relative_to_the_ground_run():
    """Road at -2 m (beams -12 and -11 deg), the -10 deg beam on the curb face 7.8 cm up (10.90 m out,
    where it would have met the road at 11.34 m), the sidewalk 12 cm up (-9 and -8 deg). The step to
    the face rises 7.8 cm over 0.61 m, under half the run; the two beams' run on level ground is
    2 (cot 10 - cot 11) = 1.05 m, so within one beam gap the step is steep. Only the face return is
    labelled: the sidewalk is the top the face leads to (rise 12 cm)."""
    xyz = column([-2.0, -2.0, -1.922, -1.88, -1.88])
    assert faces(xyz, relative=True).tolist() == [False, False, True, False, False]
    assert not faces(xyz, relative=False).any()  # the step in metres: 0.078 < 0.5 x 0.61


def test_a_steady_grade_is_no_curb_face():
    """The column climbing a steady 1.8 % grade from 9.41 m out: the steps between returns rise 1.8,
    2.1, 2.7 and 3.4 cm, each within one beam gap (steep relative to the ground run) and the later ones
    over the 2 cm noise floor, but the grade to the return before predicts each rise."""
    g, rho0 = 0.018, 2.0 / np.tan(-ALT[0])
    rho = (2.0 - g * rho0) / (np.tan(-ALT) - g)  # where each beam meets z = -2 + g (rho - rho0)
    xyz = np.column_stack([rho, np.zeros_like(rho), -2.0 + g * (rho - rho0)])
    dz = np.diff(xyz[:, 2])
    assert dz[0] < 0.02 < dz[1] and (dz[1:] > 0.02).all()
    assert not faces(xyz, relative=True).any()


def test_beam_gap_up_hand_computed():
    # rows at 0, -3 and +1 deg: up gaps 1 (0 -> 1), 3 (-3 -> 0); the highest beam takes its gap down (1)
    np.testing.assert_allclose(np.degrees(beam_gap_up(np.radians([0.0, -3.0, 1.0]))), [1.0, 3.0, 1.0])
    assert beam_gap_up(np.zeros(1)).tolist() == [0.0]


def test_region_spacing_is_the_median_range_times_beam_gap():
    """Two beams 1 deg apart: region 1 at 10 and 30 m (0.175 and 0.524 m apart up a wall: median
    0.349 m), region 2 at 5 m (0.087 m)."""
    ranges = np.array([[10.0, 30.0], [5.0, 1.0]], np.float32)
    scan = Scan(ranges, SpinningSensor.create(np.radians([0.0, -1.0]), 2))
    regions = np.array([[1, 1], [2, 0]], np.int32)
    out = region_spacing(scan, regions, 2)
    np.testing.assert_allclose(out, [0.0, 20.0 * np.radians(1.0), 5.0 * np.radians(1.0)], rtol=1e-5)


def test_car_bottom_between_two_beams_counts_from_the_beam_below():
    """A car body (0.3-0.95 m, roof to 1.5 m, no wheels) 26 m out seen by 32 beams 0.86 deg apart:
    its lowest return lies 0.51 m up, over step 5's 0.5 m; the next beam down passes 0.4 m lower
    (26 m x 0.86 deg) and missed it, so the body may reach down to 0.11 m unseen."""
    objs = [b for b in car_boxes(26.0, 3.0) if b[2] > 0 and b[0][2] > -MOUNT + 0.01]
    scan, ident = sweep(objs, beams=32, cols=2048)
    z = scan.slot_xyz()[..., 2][ident == 1]
    assert 0.5 < z.min() + MOUNT < 0.55
    found = []
    for bottom_gap in (False, True):
        det = OnlineDetector(spinning=SpinningCarParams(bottom_gap=bottom_gap))
        det.process(scan)
        found.append(float((det.process(scan).labels[ident == 1] == L.VEHICLE).mean()))
    assert found[0] < 0.1 and found[1] > 0.5
