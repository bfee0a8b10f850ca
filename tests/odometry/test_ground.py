"""Ground refinement: the map's ground planes, and height, roll and pitch recovered point to plane
while x, y and yaw stay as registered."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.odometry.ground import GroundConfig, GroundModel, ground_points
from prc_slam.odometry.kiss import KissOdometry, OdometryConfig


def rot(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def pose(t, roll=0.0, pitch=0.0, yaw=0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rot(roll, pitch, yaw)
    T[:3, 3] = t
    return T


def plane_grid(a: float, b: float, c: float, half: float = 20.0, step: float = 0.25) -> np.ndarray:
    """World points of ``z = a x + b y + c`` on a regular grid (no noise)."""
    g = np.arange(-half, half, step) + step / 2
    x, y = np.meshgrid(g, g)
    x, y = x.ravel(), y.ravel()
    return np.c_[x, y, a * x + b * y + c]


def model_of(world: np.ndarray, **kw) -> GroundModel:
    gm = GroundModel(GroundConfig(enabled=True, **kw), 100.0)
    gm.update(world, np.eye(4))
    return gm


def to_sensor(world: np.ndarray, T: np.ndarray) -> np.ndarray:
    return (world - T[:3, 3]) @ T[:3, :3]


def test_tilted_plane_offset_is_recovered():
    # a road rising 5 % along x and falling 2 % along y; the sensor 1.8 m above it at (3, -2),
    # turned 0.4 rad; the registration is 6 cm too high, 0.8 deg off in roll, -0.5 deg in pitch
    world = plane_grid(0.05, -0.02, 0.0)
    gm = model_of(world)
    truth = pose([3.0, -2.0, 0.05 * 3 - 0.02 * -2 + 1.8], yaw=0.4)
    seen = to_sensor(world[np.linalg.norm(world[:, :2] - truth[:2, 3], axis=1) < 15][::3], truth)
    guess = truth.copy()
    guess[:3, :3] = rot(np.radians(0.8), np.radians(-0.5), 0.0) @ truth[:3, :3]
    guess[2, 3] += 0.06
    out, matched, refined = gm.refine(seen, guess, sigma=0.5)
    assert refined and matched == len(seen)
    assert abs(out[2, 3] - truth[2, 3]) < 1e-4
    # roll and pitch: the vertical seen from the sensor (the yaw moves by their product, ~1e-4 rad)
    assert np.abs(out[2, :3] - truth[2, :3]).max() < 1e-5
    # x and y of the sensor are the registration's: the rotation is about the sensor's position
    assert np.array_equal(out[:2, 3], guess[:2, 3])


def test_yaw_and_horizontal_position_are_left_to_the_registration():
    # on a level plane a wrong yaw or x cannot be seen: the refinement must not touch them
    world = plane_grid(0.0, 0.0, 0.0)
    gm = model_of(world)
    truth = pose([0.0, 0.0, 1.8])
    seen = to_sensor(world[np.linalg.norm(world[:, :2], axis=1) < 15][::3], truth)
    guess = pose([0.3, -0.2, 1.7], yaw=0.1)
    out, _, refined = gm.refine(seen, guess, sigma=0.5)
    assert refined
    assert abs(out[2, 3] - 1.8) < 1e-4
    np.testing.assert_allclose(out[:2, 3], [0.3, -0.2], atol=1e-12)
    assert abs(np.arctan2(out[1, 0], out[0, 0]) - 0.1) < 1e-9


def test_points_far_off_the_ground_do_not_pull():
    # a third of the "ground" points 0.6 m up (a kerb wall, a misclassified car): beyond the gate
    world = plane_grid(0.0, 0.0, 0.0)
    gm = model_of(world)
    truth = pose([0.0, 0.0, 1.8])
    seen = to_sensor(world[np.linalg.norm(world[:, :2], axis=1) < 15][::3], truth)
    seen[::3, 2] += 0.6
    guess = truth.copy()
    guess[2, 3] += 0.03
    out, matched, _ = gm.refine(seen, guess, sigma=0.3)
    assert matched == len(seen) - len(seen[::3])
    assert abs(out[2, 3] - 1.8) < 1e-4


def test_too_few_matches_leave_the_pose():
    world = plane_grid(0.0, 0.0, 0.0)
    gm = model_of(world, min_matches=50)
    guess = pose([0.0, 0.0, 1.9])
    seen = to_sensor(world[:20], pose([0.0, 0.0, 1.8]))
    out, matched, refined = gm.refine(seen, guess, sigma=0.5)
    assert not refined and matched == 20
    assert np.array_equal(out, guess)
    empty = GroundModel(GroundConfig(enabled=True), 100.0)
    out, matched, refined = empty.refine(seen, guess, sigma=0.5)
    assert (matched, refined) == (0, False) and np.array_equal(out, guess)


def test_cells_without_a_plane_are_not_matched():
    # one scan line per cell (points along x only): the tilt across it is unknown, no plane
    x = np.linspace(0.05, 9.95, 400)
    line = np.c_[x, np.full_like(x, 0.5), np.zeros_like(x)]
    gm = model_of(line, min_matches=3)
    seen = to_sensor(line[::7], pose([0.0, 0.0, 1.8]))
    _, matched, refined = gm.refine(seen, pose([0.0, 0.0, 1.9]), sigma=0.5)
    assert matched == 0 and not refined
    # a bumpy cell (RMS 0.2 m about its plane) is not planar either; rough ground (0.08 m, within
    # max_rms = 0.1 m, the forest floor's median) is
    for bump, planar in ((0.2, False), (0.08, True)):
        rng = np.random.default_rng(1)
        bumpy = plane_grid(0.0, 0.0, 0.0, half=3.0)
        bumpy[:, 2] += rng.choice([-bump, bump], len(bumpy))
        gm = model_of(bumpy, min_matches=3)
        _, matched, _ = gm.refine(to_sensor(bumpy[::5], pose([0.0, 0.0, 1.8])), pose([0.0, 0.0, 1.8]), sigma=0.5)
        assert (matched > 0) == planar


def test_cells_hold_at_most_max_points_and_far_cells_are_dropped():
    gm = GroundModel(GroundConfig(enabled=True, max_points=4), 30.0)
    gm.update(np.array([[0.2, 0.2, 0.0]] * 10 + [[0.7, 0.7, 1.0]]), np.eye(4))
    h = int(np.flatnonzero(gm.keys[:, 2])[0])
    assert gm.n == 1 and gm.moments[h, 0] == 4 and gm.moments[h, 3] == 0.0  # the fifth point on was not taken
    size = gm.keys.shape[0]
    far = pose([200.0, 0.0, 0.0])
    gm.update(plane_grid(0.0, 0.0, 0.0, half=40.0, step=1.0), far)  # enough cells to rebuild the table
    assert gm.keys.shape[0] >= size
    cells = gm.keys[gm.keys[:, 2] == 1]
    assert not ((cells[:, 0] == 0) & (cells[:, 1] == 0)).any()  # the cell at the origin is 200 m away
    assert gm.n == len(cells) == 80 * 80


def test_bad_input_is_refused():
    gm = GroundModel(GroundConfig(enabled=True), 100.0)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        gm.update(np.zeros((4, 2)), np.eye(4))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        gm.refine(np.zeros(3), np.eye(4), 0.5)


def test_ground_points_by_label_and_range():
    pts = np.array([[1.0, 0, 0], [50.0, 0, 0], [3.0, 0, 0], [0.1, 0, 0]])
    lab = np.array([L.GROUND, L.GROUND, L.BUILDING, L.GROUND], np.uint8)
    np.testing.assert_array_equal(ground_points(pts, lab, [L.GROUND], 0.5, 40.0), pts[[0]])
    np.testing.assert_array_equal(ground_points(pts, lab, [L.GROUND, L.BUILDING], 0.5, 40.0), pts[[0, 2]])
    assert ground_points(pts, lab, [L.CURB], 0.0, 100.0).shape == (0, 3)


@settings(max_examples=25, deadline=None)
@given(
    a=st.floats(-0.08, 0.08),
    b=st.floats(-0.08, 0.08),
    dz=st.floats(-0.15, 0.15),
    droll=st.floats(-0.02, 0.02),
    dpitch=st.floats(-0.02, 0.02),
    yaw=st.floats(-np.pi, np.pi),
)
def test_any_small_offset_on_any_gentle_slope_is_recovered(a, b, dz, droll, dpitch, yaw):
    world = plane_grid(a, b, -1.0, half=16.0)
    gm = model_of(world)
    truth = pose([1.0, 2.0, a + 2 * b - 1.0 + 1.8], yaw=yaw)
    seen = to_sensor(world[np.linalg.norm(world[:, :2] - truth[:2, 3], axis=1) < 12][::2], truth)
    guess = truth.copy()
    guess[:3, :3] = rot(droll, dpitch, 0.0) @ truth[:3, :3]
    guess[2, 3] += dz
    out, _, refined = gm.refine(seen, guess, sigma=1.0)
    assert refined
    assert abs(out[2, 3] - truth[2, 3]) < 1e-4
    # the robust weights make Gauss-Newton converge linearly: after its 5 iterations from a tilt of
    # up to 0.028 rad the last bit of tilt left is ~1e-5 rad (2e-5 at worst in 300 draws)
    assert np.abs(out[2, :3] - truth[2, :3]).max() < 1e-4


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim") / "urban"
    write_sequence(Simulator(SimConfig(frames=8, seed=3)), root)
    return open_dataset(root)


def test_odometry_refines_with_labels_only(drive):
    """With ``ground.enabled`` the frames given labels are refined (matched ground points counted
    from the second frame on); without labels the odometry is KISS-ICP's, pose for pose."""
    on = KissOdometry(OdometryConfig(ground=GroundConfig(enabled=True)))
    plain = KissOdometry(OdometryConfig())
    unlabelled = KissOdometry(OdometryConfig(ground=GroundConfig(enabled=True)))
    for k, scan in enumerate(drive):
        if k == 5:
            break
        pts, t = scan.points(), scan.point_times()
        labels = np.asarray(scan.reference_labels(), dtype=np.uint8)
        on.register(pts, t, labels, scan.meta.get("frame_time"))
        a = plain.register(pts, t, None, scan.meta.get("frame_time"))
        b = unlabelled.register(pts, t, None, scan.meta.get("frame_time"))
        np.testing.assert_allclose(a, b, atol=1e-6)  # KISS-ICP's threaded sums differ in the last bits
    assert on.ground_matches[0] == 0 and min(on.ground_matches[1:]) > 100
    assert unlabelled.ground_matches == []
    with pytest.raises(ValueError, match="labels of shape"):
        on.register(pts, t, labels[:-1], None)
