"""Degeneracy of a registration: a corridor's axis is found and flagged, cross-structure lifts
the flag, and the odometry keeps the constant-velocity prediction along the flagged direction."""

from __future__ import annotations

import numpy as np
import pytest

from prc_slam.odometry.degeneracy import DegeneracyConfig, analyse, conditioning
from prc_slam.odometry.group_map import GroupVoxelMap
from prc_slam.odometry.kiss import KissOdometry, OdometryConfig

HALF_WIDTH, FLOOR, CEILING = 4.0, -1.7, 3.8


def corridor_points(rng: np.random.Generator, x0: float, x1: float, n: int) -> np.ndarray:
    """Random points on the walls, floor and ceiling of a corridor along x between ``x0`` and
    ``x1`` (world frame, sensor height 0), with 5 mm noise."""
    k = n // 4
    x = rng.uniform(x0, x1, 4 * k)
    u = rng.uniform(0.0, 1.0, 4 * k)
    y = np.concatenate([np.full(k, -HALF_WIDTH), np.full(k, HALF_WIDTH), (2 * u[2 * k :] - 1) * HALF_WIDTH])
    z = np.concatenate([FLOOR + u[: 2 * k] * (CEILING - FLOOR), np.full(k, FLOOR), np.full(k, CEILING)])
    return np.column_stack([x, y, z]) + rng.normal(0.0, 0.005, (4 * k, 3))


def cross_walls(rng: np.random.Generator, xs: list[float], n: int) -> np.ndarray:
    """Points on 1 m deep buttresses across both walls at ``xs``: faces normal to the axis."""
    out = []
    for x in xs:
        for side in (-1.0, 1.0):
            y = side * (HALF_WIDTH - rng.uniform(0.0, 1.0, n))
            z = rng.uniform(FLOOR, CEILING, n)
            out.append(np.column_stack([np.full(n, x), y, z]))
    return np.concatenate(out) + rng.normal(0.0, 0.005, (2 * n * len(xs), 3))


def map_of(points: np.ndarray, voxel: float = 0.5) -> GroupVoxelMap:
    gmap = GroupVoxelMap(voxel, 100.0, 20)
    gmap.update(points, np.zeros(len(points), np.int64), np.eye(4))
    return gmap


def test_corridor_axis_is_the_one_degenerate_direction():
    rng = np.random.default_rng(0)
    gmap = map_of(corridor_points(rng, -30, 30, 40000))
    src = corridor_points(rng, -20, 20, 3000)
    cond = analyse(src, np.zeros(len(src), np.int64), gmap.index(), 0.5, 0.1, np.eye(4), 0.02)
    assert cond.degenerate == 1
    (d,) = cond.directions()
    assert d["kind"] == "translation"
    assert abs(d["direction"][0]) > 0.99  # along the corridor
    assert d["ratio"] < 0.02
    # every other direction holds at least a tenth of the best one's information
    assert cond.eigenvalues[1] > 0.1 * cond.eigenvalues[-1]


def test_cross_structure_lifts_the_flag():
    rng = np.random.default_rng(1)
    walls = cross_walls(rng, [-12.0, -5.0, 3.0, 11.0], 400)
    gmap = map_of(np.concatenate([corridor_points(rng, -30, 30, 40000), walls]))
    src = np.concatenate([corridor_points(rng, -20, 20, 3000), cross_walls(rng, [-12.0, -5.0, 3.0, 11.0], 60)])
    cond = analyse(src, np.zeros(len(src), np.int64), gmap.index(), 0.5, 0.1, np.eye(4), 0.02)
    assert cond.degenerate == 0, cond.directions()
    assert cond.ratio > 0.02


def test_point_to_point_normal_matrix_cannot_see_the_corridor():
    """Why the surfaces' information is used: KISS-ICP's own point-to-point normal matrix has the
    translation block sum(w) I, isotropic in a corridor."""
    rng = np.random.default_rng(2)
    src = corridor_points(rng, -20, 20, 2000)
    J = np.zeros((len(src), 3, 6))
    J[:, :, :3] = np.eye(3)
    x, y, z = src.T
    J[:, 0, 4], J[:, 0, 5], J[:, 1, 3], J[:, 1, 5], J[:, 2, 3], J[:, 2, 4] = z, -y, -z, x, y, -x
    H = np.einsum("nka,nkb->ab", J, J)
    np.testing.assert_allclose(H[:3, :3], len(src) * np.eye(3))


def test_projection_drops_only_the_degenerate_components():
    H = np.diag([1e-6, 5.0, 6.0, 7.0, 8.0, 9.0])
    cond = conditioning(H, 100, np.full(3, 4.0), 0.02)
    assert cond.degenerate == 1
    xi = np.array([0.8, 0.1, -0.05, 0.01, -0.02, 0.03])
    out = cond.project(xi)
    assert abs(out[0]) < 1e-12
    np.testing.assert_allclose(out[1:], xi[1:], atol=1e-12)
    assert cond.directions()[0]["direction"] == [1.0, 0.0, 0.0]


#: the drive's cross-structure (buttresses at these x) and the odometry's range: featureless beyond
#: x = 14 + 20 m
STRUCTURE, RANGE, STEP = [1.0, 3.5, 5.0, 8.0, 9.5, 12.0, 14.0], 20.0, 0.5


def drive(keep: bool, frames: int = 90) -> tuple[np.ndarray, KissOdometry]:
    """A sensor moving ``STEP`` m per 0.1 s frame along a corridor; returns the x positions
    estimated and the odometry."""
    rng = np.random.default_rng(3)
    config = OdometryConfig(
        max_range=RANGE, voxel_size=1.0, deskew=False, degeneracy=DegeneracyConfig(keep_prediction=keep)
    )
    odo = KissOdometry(config)
    structure = cross_walls(rng, STRUCTURE, 400)  # the same returns every frame: a fixed texture
    for i in range(frames):
        x = i * STEP
        pts = np.concatenate([corridor_points(rng, x - RANGE, x + RANGE, 4000), structure])
        pts = pts[np.linalg.norm(pts - [x, 0, 0], axis=1) < RANGE]
        odo.register(pts - [x, 0.0, 0.0], frame_time=0.1 * i)
    return np.array(odo.poses)[:, 0, 3], odo


@pytest.fixture(scope="module")
def drives():
    return {keep: drive(keep) for keep in (True, False)}


def test_featureless_frames_are_flagged_along_the_axis(drives):
    xs, odo = drives[True]
    flagged = {d["frame"] for d in odo.degenerate_frames if d["kind"] == "translation"}
    featureless = [i for i in range(len(xs)) if i * STEP > STRUCTURE[-1] + RANGE]
    assert len(set(featureless) & flagged) >= 0.9 * len(featureless)
    assert all(abs(d["direction"][0]) > 0.95 for d in odo.degenerate_frames if d["kind"] == "translation")
    assert all(d["kept_prediction"] for d in odo.degenerate_frames)
    structured = [i for i in range(3, len(xs)) if i * STEP < STRUCTURE[-1]]  # cross-structure around
    assert not flagged & set(structured)


def test_prediction_is_kept_along_the_flagged_axis(drives):
    """Without the handling the registration slides towards staying put in the featureless
    stretch (the map's nearest points pull it back); with it the constant velocity carries on."""
    kept, _ = drives[True]
    slid, _ = drives[False]
    truth = np.arange(len(kept)) * STEP
    assert abs(slid[-1] - truth[-1]) > 3 * abs(kept[-1] - truth[-1])
    # in the featureless stretch the kept pose moves on at the velocity it entered with
    steps = np.diff(kept[-15:])
    assert steps.min() > 0.8 * STEP
