"""Class-aware registration: correspondences stay within class groups, a known motion is
recovered, weights behave, and the forest walk's trajectory is guarded by a golden file."""

from __future__ import annotations

import numpy as np
import pytest

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.config import Config, PRCConfig
from prc_slam.odometry.classaware import (
    GROUP_NAMES,
    ClassAwareConfig,
    ClassAwareOdometry,
    GroupVoxelMap,
    group_of_codes,
    icp,
)
from prc_slam.odometry.compare import run_compare
from prc_slam.odometry.ground import GroundConfig
from prc_slam.odometry.kiss import KissOdometry, OdometryConfig
from prc_slam.testing import assert_trajectory_close

TRUNK, STRUCTURE, GROUND = (GROUP_NAMES.index(g) for g in ("trunk", "structure", "ground"))


def test_groups_of_codes():
    g = group_of_codes()
    assert g[L.TRUNK] == TRUNK and g[L.BUILDING] == g[L.POLE] == STRUCTURE and g[L.CURB] == GROUND
    assert g[L.VEHICLE] == g[L.UNCLASSIFIED] == GROUP_NAMES.index("other")
    with pytest.raises(ValueError, match="unknown class groups"):
        ClassAwareConfig(weights={"leaves": 1.0}).weight_array()
    with pytest.raises(ValueError, match="no class-aware weights"):
        ClassAwareConfig.for_mode("desert")
    assert ClassAwareConfig.for_mode("forest").weights["vegetation"] < ClassAwareConfig().weights["vegetation"]


def test_correspondences_never_cross_groups_even_when_nearer():
    # map: a trunk point at the origin and a building point 0.4 m away; the source point is a
    # building point 0.05 m from the trunk point: it must pair with the building point
    gmap = GroupVoxelMap(1.0, 100.0, 20)
    gmap.update(np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0]]), np.array([TRUNK, STRUCTURE]), np.eye(4))
    index = gmap.index()
    src = np.array([[0.05, 0.0, 0.0], [0.35, 0.0, 0.0]])
    weights = np.ones(len(GROUP_NAMES))
    for src_grp, expect in (([STRUCTURE, STRUCTURE], [STRUCTURE, STRUCTURE]), ([TRUNK, GROUND], [TRUNK, -1])):
        _, counts, partner, _ = icp(
            src, np.array(src_grp), weights, *index, 1.0, np.eye(4), 2.0, 1.0, 1, 1e-4
        )  # fmt: skip
        assert partner.tolist() == expect  # the ground point finds no ground in the map
        assert counts.sum() == sum(e >= 0 for e in expect)


@pytest.mark.parametrize("max_dist", [0.05, 0.3, 0.9, 2.5])
def test_pruned_search_equals_all_27_voxels(max_dist):
    """The correspondence search skips voxels farther than its best match: the brute force's
    nearest distance over the 27 voxels around each query (none beyond ``max_dist``), near
    voxel faces and corners too."""
    from prc_slam.odometry.guard import nearest_map_point

    rng = np.random.default_rng(int(max_dist * 100))
    gmap = GroupVoxelMap(0.5, 100.0, 20)
    pts = np.round(rng.uniform(-2, 2, (3000, 3)), 2)  # on a 1 cm grid: ties and points on faces
    groups = rng.integers(0, 2, len(pts))
    gmap.update(pts, groups, np.eye(4))
    table, coords, first, count, mpts = gmap.index()
    inv = 1.0 / 0.5
    queries = np.vstack([rng.uniform(-2, 2, (400, 3)), np.round(rng.uniform(-2, 2, (200, 3)) * 2) / 2])
    slots = np.concatenate([np.arange(f, f + c) for f, c in zip(first, count, strict=True)])
    vk = coords[np.repeat(np.arange(len(count)), count)]  # voxel key of each map point (slot order)
    mp = mpts[slots]
    for p in queries:
        for g in (0, 1):
            q, d2 = nearest_map_point(p, g, table, coords, first, count, mpts, inv, max_dist**2)
            k = np.floor(p * inv).astype(np.int64)
            near = (np.abs(vk[:, :2] - k[:2]) <= 1).all(axis=1) & (np.abs(vk[:, 2] // 8 - k[2]) <= 1)
            near &= vk[:, 2] % 8 == g
            dd = ((mp - p) ** 2).sum(axis=1)
            cand = np.flatnonzero(near & (dd < max_dist**2))
            if len(cand) == 0:
                assert q == -1
            else:
                assert d2 == dd[cand].min() and q in slots[cand] and ((mpts[q] - p) ** 2).sum() == d2


def _room(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Ground, two walls at right angles, and trunks, with their codes."""
    g = rng.uniform([-20, -20, 0], [20, 20, 0], (6000, 3))
    w1 = np.column_stack([rng.uniform(-20, 20, 3000), np.full(3000, 15.0), rng.uniform(0, 6, 3000)])
    w2 = np.column_stack([np.full(3000, -12.0), rng.uniform(-20, 20, 3000), rng.uniform(0, 6, 3000)])
    trunks = []
    for cx, cy in [(5, 3), (-4, -6), (8, -9), (-7, 7)]:
        a, z = rng.uniform(0, 2 * np.pi, 600), rng.uniform(0, 5, 600)
        trunks.append(np.column_stack([cx + 0.2 * np.cos(a), cy + 0.2 * np.sin(a), z]))
    pts = np.concatenate([g, w1, w2, *trunks]) - [0, 0, 1.7]
    codes = np.concatenate([np.full(6000, L.GROUND), np.full(6000, L.BUILDING), np.full(2400, L.TRUNK)])
    return pts + rng.normal(0, 0.01, pts.shape), codes.astype(np.uint8)


def test_two_frame_known_motion_is_recovered():
    pts, codes = _room(np.random.default_rng(1))
    c, s = np.cos(np.radians(2.0)), np.sin(np.radians(2.0))
    motion = np.array([[c, -s, 0, 0.4], [s, c, 0, -0.1], [0, 0, 1, 0.02], [0, 0, 0, 1.0]])
    moved = (pts - motion[:3, 3]) @ motion[:3, :3]  # the same scene seen from the moved sensor
    odo = ClassAwareOdometry(OdometryConfig(deskew=False))
    odo.register(pts, None, codes)
    pose = odo.register(moved, None, codes)
    assert np.linalg.norm(pose[:3, 3] - motion[:3, 3]) < 0.01
    angle = np.degrees(np.arccos(np.clip((np.trace(pose[:3, :3].T @ motion[:3, :3]) - 1) / 2, -1, 1)))
    assert angle < 0.05
    assert odo.correspondences[-1][TRUNK] > 0 and odo.correspondences[-1][STRUCTURE] > 0
    with pytest.raises(ValueError, match="labels"):
        odo.register(pts, None, codes[:10])


def test_zero_weight_leaves_a_group_out():
    pts, codes = _room(np.random.default_rng(2))
    odo = ClassAwareOdometry(OdometryConfig(deskew=False), ClassAwareConfig(weights={"trunk": 0.0}))
    odo.register(pts, None, codes)
    odo.register(pts, None, codes)
    assert odo.correspondences[-1][TRUNK] == 0 and odo.correspondences[-1][GROUND] > 0


def _moves(pts: np.ndarray, n: int) -> list[np.ndarray]:
    """The room seen from a sensor turning 1 deg and moving 0.3 m along x per frame."""
    out = []
    for i in range(n):
        c, s = np.cos(np.radians(1.0 * i)), np.sin(np.radians(1.0 * i))
        pose = np.array([[c, -s, 0, 0.3 * i], [s, c, 0, 0.0], [0, 0, 1, 0.0], [0, 0, 0, 1.0]])
        out.append((pts - pose[:3, 3]) @ pose[:3, :3])
    return out


def test_sweep_without_anchors_is_registered_as_the_prc_variant_does():
    """No trunk in the sweep: nothing anchors the class-aware matching, and the sweep is
    registered by KISS-ICP on the same points (the prc variant's registration), kept in step."""
    pts, codes = _room(np.random.default_rng(4))
    room = codes != L.TRUNK
    pts, codes = pts[room], codes[room]
    config = OdometryConfig(deskew=False)
    odo, prc = ClassAwareOdometry(config), KissOdometry(config)
    for i, frame in enumerate(_moves(pts, 4)):
        a = odo.register(frame, None, codes, frame_time=0.1 * i)
        b = prc.register(frame, None, codes, frame_time=0.1 * i)  # the prc variant gives its labels too
        np.testing.assert_allclose(a, b, atol=1e-6)
    assert odo.classaware_frames == [] and odo.anchor_ratio == [None, 0.0, 0.0, 0.0]
    assert np.linalg.norm(a[:3, 3] - [0.9, 0.0, 0.0]) < 0.02


@pytest.mark.parametrize(("stems", "anchored"), [([(5, 3)], False), ([(5, 3), (-4, -6), (8, -9), (-7, 7)], True)])
def test_one_stem_leaves_the_yaw_free_several_anchor_the_sweep(stems, anchored):
    rng = np.random.default_rng(5)
    pts, codes = _room(rng)
    keep = codes != L.TRUNK
    trunks = []
    for cx, cy in stems:
        a, z = rng.uniform(0, 2 * np.pi, 600), rng.uniform(0, 5, 600)
        trunks.append(np.column_stack([cx + 0.2 * np.cos(a), cy + 0.2 * np.sin(a), z - 1.7]))
    pts = np.concatenate([pts[keep], *trunks])
    codes = np.concatenate([codes[keep], np.full(600 * len(stems), L.TRUNK, np.uint8)])
    odo = ClassAwareOdometry(OdometryConfig(deskew=False))
    poses = [odo.register(f, None, codes, frame_time=0.1 * i) for i, f in enumerate(_moves(pts, 3))]
    assert (odo.classaware_frames == [1, 2]) == anchored, odo.anchor_ratio
    assert (odo.anchor_ratio[1] >= odo.config.degeneracy.ratio) == anchored
    assert np.linalg.norm(poses[-1][:3, 3] - [0.6, 0.0, 0.0]) < 0.02


@pytest.fixture(scope="module")
def forest_walk(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim") / "forest"
    write_sequence(Simulator(SimConfig(scene="forest", sensor="vlp16", frames=30, seed=3, wind=0.3)), root)
    return open_dataset(root)


def test_golden_forest_walk(forest_walk, trajectory_regression):
    # deskewing on (the default) since the time convention was fixed
    cfg = Config(
        prc=PRCConfig.preset("multibeam", mode="forest"),
        odometry=OdometryConfig(),
        classaware=ClassAwareConfig.for_mode("forest"),
    )
    res = run_compare(iter(forest_walk), cfg, ["prc+classaware"])
    est = res.estimate_in_world("prc+classaware")
    assert_trajectory_close(est, forest_walk.poses, ate_tol=0.3, rpe_tol=0.3)
    m = res.metrics()["variants"]["prc+classaware"]
    assert len(m["correspondences_per_group"]["trunk"]) == 30 and m["correspondences_per_group_mean"]["trunk"] > 0
    trajectory_regression.check(est, ate_tol=0.02, rpe_tol=0.02)


def test_cli_class_aware_variant_and_matching(forest_walk, tmp_path):
    import json

    from typer.testing import CliRunner

    from prc_slam.cli import app

    runner = CliRunner()
    root = str(forest_walk.root)
    bad = runner.invoke(app, ["odometry", root, "--filter", "none", "--matching", "class-aware"])
    assert bad.exit_code == 2 and "needs PRC labels" in bad.output
    res = runner.invoke(
        app,
        [
            "odometry",
            root,
            "--matching",
            "class-aware",
            "--mode",
            "forest",
            "--max-frames",
            "4",
            "--json",
            str(tmp_path / "o.json"),
        ],
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "o.json").read_text())["variants"]["prc+classaware"]
    assert m["frames"] == 4 and set(m["correspondences_per_group"]) == set(GROUP_NAMES)
    res = runner.invoke(
        app, ["compare", root, "--variants", "prc,prc+magic", "--max-frames", "2", "--out", str(tmp_path)]
    )
    assert res.exit_code == 2 and "unknown variants" in res.output


def test_group_voxel_map_follows_kiss_rules():
    gmap = GroupVoxelMap(1.0, 10.0, 4)  # resolution 1 / sqrt(4) = 0.5 m
    pts = np.array(
        [[0.1, 0.1, 0.1], [0.2, 0.1, 0.1], [0.9, 0.9, 0.9], [0.1, 0.9, 0.1], [0.9, 0.1, 0.9], [0.5, 0.9, 0.9]]
    )
    gmap.update(pts, np.zeros(6, np.int64), np.eye(4))
    cloud, groups = gmap.point_cloud()
    # the second point is too close to the first; the voxel is full after four
    assert len(cloud) == 4 and not np.any(np.all(cloud == pts[1], axis=1)) and (groups == 0).all()
    gmap.update(pts[:1], np.array([STRUCTURE]), np.eye(4))  # same voxel, other group: its own voxel
    assert len(gmap.point_cloud()[0]) == 5 and gmap.n == 2
    far = np.eye(4)
    far[:3, 3] = [50.0, 0.0, 0.0]
    gmap.update(np.zeros((1, 3)), np.array([TRUNK]), far)  # moving away drops the old voxels
    cloud, groups = gmap.point_cloud()
    assert cloud.tolist() == [[50.0, 0.0, 0.0]] and groups.tolist() == [TRUNK]
    many = np.random.default_rng(0).uniform(-9, 9, (5000, 3))
    gmap.update(many, np.full(5000, GROUND), np.eye(4))  # grows and rehashes
    cloud, groups = gmap.point_cloud()
    assert len(cloud) > 2000 and (groups == GROUND).all()  # the trunk voxel is 50 m away now


@pytest.mark.parametrize("ground", [True, False])
def test_anchored_sweeps_get_the_ground_refinement(ground):
    """The sweeps matched class-aware are refined against the ground model (height, roll and
    pitch, ``odometry.ground``) that the prc registration it falls back on refines against too:
    one model, shared; with ``ground.enabled`` off neither refines."""
    pts, codes = _room(np.random.default_rng(6))
    odo = ClassAwareOdometry(OdometryConfig(deskew=False, ground=GroundConfig(enabled=ground)))
    poses = [odo.register(f, None, codes, frame_time=0.1 * i) for i, f in enumerate(_moves(pts, 5))]
    assert odo.classaware_frames == [1, 2, 3, 4]
    if ground:
        assert odo.ground is odo.fallback.ground and odo.ground_refined is odo.fallback.ground_refined
        # every sweep after the first: ~4 ground points a frame fall in each 1 m cell here, and a
        # cell's plane needs ground.min_points (5), so the first frame's cells alone give too few
        assert odo.ground_refined == [1, 2, 3, 4]
    else:
        assert odo.ground is None and odo.ground_refined == []
    assert np.linalg.norm(poses[-1][:3, 3] - [1.2, 0.0, 0.0]) < 0.02
    assert abs(poses[-1][2, 3]) < 0.005


def _stems(rng: np.random.Generator, centres, n: int = 400) -> np.ndarray:
    """Points on the faces of upright stems of radius 0.2 m (a half circle each, facing -x), 4 m tall."""
    out = []
    for cx, cy in centres:
        a, z = rng.uniform(0.5 * np.pi, 1.5 * np.pi, n), rng.uniform(-1.0, 3.0, n)
        out.append(np.column_stack([cx + 0.2 * np.cos(a), cy + 0.2 * np.sin(a), z]))
    return np.concatenate(out)


def _trunk_map(pts: np.ndarray) -> GroupVoxelMap:
    gmap = GroupVoxelMap(1.0, 100.0, 20)
    gmap.update(pts, np.full(len(pts), TRUNK, np.int64), np.eye(4))
    return gmap


def test_point_to_line_gradient_and_information_match_finite_differences():
    """For one correspondence to a stem, b = J^T P r and H = J^T P J (point to line, ``P = I - d d^T``)
    are the gradient and Gauss-Newton matrix of ``|P r|^2 / 2`` under ``T <- exp(dx) T``."""
    from prc_slam.odometry.classaware import _exp_se3, _linearise, _projector

    gmap = _trunk_map(_stems(np.random.default_rng(7), [(5.0, 1.0)]))
    src = np.array([[4.9, 1.1, 0.4]])
    c, s = np.cos(0.03), np.sin(0.03)
    T = np.array([[c, -s, 0, 0.05], [s, c, 0, -0.04], [0, 0, 1, 0.3], [0, 0, 0, 1.0]])
    kinds = np.array([1, 0, 0, 0, 0], np.int64)
    weights = np.ones(len(GROUP_NAMES))
    kernel = 1e9  # the Geman-McClure weight is 1 to within 1e-9
    H, b, counts, _ = _linearise(
        src, np.array([TRUNK]), weights, kinds, 0.5, *gmap.index(), 1.0, 4.0, kernel, T, 1, np.full(1, -1),
        np.empty((1, 3, 3)),
    )  # fmt: skip
    assert counts[0, TRUNK] == 1
    p = T[:3, :3] @ src[0] + T[:3, 3]
    idx = gmap.index()
    from prc_slam.odometry.guard import nearest_map_point

    q = nearest_map_point(p, TRUNK, *idx, 1.0, 4.0)[0]
    P = np.eye(3)
    _projector(P, 1, idx[4][q], TRUNK, *idx, 1.0, 0.5)
    d = np.linalg.eigh(np.eye(3) - P)[1][:, -1]
    assert abs(d[2]) > 0.99  # the stem's direction is upright

    def res(dx):
        pp = (_exp_se3(dx) @ T)[:3, :3] @ src[0] + (_exp_se3(dx) @ T)[:3, 3]
        return P @ (pp - idx[4][q])

    eps = 1e-6
    Jn = np.column_stack([(res(e) - res(-e)) / (2 * eps) for e in np.eye(6) * eps])
    Hs = np.triu(H[0]) + np.triu(H[0], 1).T
    np.testing.assert_allclose(b[0], Jn.T @ res(np.zeros(6)), atol=1e-6)
    np.testing.assert_allclose(Hs, Jn.T @ Jn, atol=1e-5)
    along = np.concatenate([0.1 * d, np.zeros(3)])  # a shift along the stem changes nothing
    np.testing.assert_allclose(res(along), res(np.zeros(6)), atol=1e-9)
    assert np.linalg.norm(res(np.array([0.1, 0, 0, 0, 0, 0])) - res(np.zeros(6))) > 0.09  # across it, all


@pytest.mark.parametrize("kind", ["line", "point"])
def test_stems_to_their_lines_fix_x_y_and_yaw_not_the_height(kind):
    """Upright stems matched point to line constrain the motion across them (x, y and, from stems apart, yaw)
    and hardly the motion along them (only through the sampling's tilt of each voxel's line); point to point
    claims the height as firmly as x and y, and a sparser sweep of the same stems moves it (the nearest map
    point's offset along a stem is sampling, not motion)."""
    from prc_slam.odometry.classaware import _linearise

    rng = np.random.default_rng(8)
    centres = [(5.0, 1.0), (-4.0, 6.0), (3.0, -7.0), (-6.0, -5.0)]
    gmap = _trunk_map(_stems(rng, centres))
    frame = _stems(rng, centres, 150)  # a sparser sweep of the same stems from the origin
    group = np.full(len(frame), TRUNK, np.int64)
    c, s = np.cos(np.radians(0.5)), np.sin(np.radians(0.5))
    guess = np.array([[c, -s, 0, 0.08], [s, c, 0, -0.06], [0, 0, 1, 0.0], [0, 0, 0, 1.0]])
    kinds = ClassAwareConfig(residuals={"trunk": kind}).kind_array()
    weights = np.ones(len(GROUP_NAMES))
    T, counts, _, _ = icp(frame, group, weights, *gmap.index(), 1.0, guess, 0.6, 0.2, 100, 1e-6, kinds, 0.5)
    assert counts[TRUNK] > 0.9 * len(frame)
    assert np.abs(T[:2, 3]).max() < 0.01
    assert (abs(T[2, 3]) < 0.01) == (kind == "line")  # point to point: the height slides with the sampling
    assert abs(np.degrees(np.arctan2(T[1, 0], T[0, 0]))) < 0.05
    cache = np.full(len(frame), -1), np.empty((len(frame), 3, 3))
    H = _linearise(frame, group, weights, kinds, 0.5, *gmap.index(), 1.0, 0.36, 0.2, T, 1, *cache)[0][0]
    assert (H[2, 2] < 0.1 * min(H[0, 0], H[1, 1])) == (kind == "line")
    with pytest.raises(ValueError, match="unknown class groups"):
        ClassAwareConfig(residuals={"stem": "line"}).kind_array()


def test_sweep_velocity_gradient_matches_finite_differences():
    """The velocity columns of :func:`_linearise_sweep`: a change ``dv`` of the sweep's velocity moves a point
    deskewed to the reference instant by ``exp(s dv)`` (``s`` its time in frame intervals) before the pose."""
    from prc_slam.odometry.classaware import _exp_se3, _linearise_sweep, _projector
    from prc_slam.odometry.guard import nearest_map_point
    from prc_slam.odometry.kiss import deskew_points

    gmap = _trunk_map(_stems(np.random.default_rng(9), [(5.0, 1.0)]))
    idx = gmap.index()
    src, s = np.array([[4.9, 1.1, 0.4]]), np.array([0.37])
    c, sn = np.cos(0.03), np.sin(0.03)
    T = np.array([[c, -sn, 0, 0.05], [sn, c, 0, -0.04], [0, 0, 1, 0.3], [0, 0, 0, 1.0]])
    kinds = np.array([1, 0, 0, 0, 0], np.int64)
    H, b, counts, _ = _linearise_sweep(src, s, np.array([TRUNK]), np.ones(len(GROUP_NAMES)), kinds, 0.5, *idx, 1.0,
                                       4.0, 1e9, T, np.full(1, -1), np.empty((1, 3, 3)))  # fmt: skip
    assert counts[TRUNK] == 1
    p = T[:3, :3] @ src[0] + T[:3, 3]
    q = nearest_map_point(p, TRUNK, *idx, 1.0, 4.0)[0]
    P = np.eye(3)
    _projector(P, 1, idx[4][q], TRUNK, *idx, 1.0, 0.5)

    def res(d):
        moved = deskew_points(src, s, 0.0, 1.0, _exp_se3(d[6:]))[0]  # exp(s dv) p
        Tn = _exp_se3(d[:6]) @ T
        return P @ (Tn[:3, :3] @ moved + Tn[:3, 3] - idx[4][q])

    eps = 1e-6
    Jn = np.column_stack([(res(e) - res(-e)) / (2 * eps) for e in np.eye(12) * eps])
    np.testing.assert_allclose(b, Jn.T @ res(np.zeros(12)), atol=1e-6)
    np.testing.assert_allclose(H, Jn.T @ Jn, atol=1e-5)


def test_sweep_registration_recovers_the_velocity_the_deskewing_missed():
    """Stems seen by a sensor turning 2 deg and moving 0.1 m a frame interval within its sweep, not deskewed:
    the constant-pose registration of the distorted sweep is off, the sweep registration finds the motion."""
    from prc_slam.odometry.classaware import icp_sweep
    from prc_slam.odometry.kiss import deskew_points, se3_exp

    rng = np.random.default_rng(10)
    az = np.radians(np.arange(0, 360, 40) + 10.0)
    centres = [(8 * np.cos(a), 8 * np.sin(a)) for a in az]
    gmap = _trunk_map(_stems(rng, centres))
    ref = _stems(rng, centres, 150)  # the sweep at the reference instant
    s = np.arctan2(ref[:, 1], ref[:, 0]) / (2 * np.pi)  # a counter-clockwise turn from -180 deg: s in [-0.5, 0.5]
    xi = np.array([0.1, 0.0, 0.0, 0.0, 0.0, np.radians(2.0)])
    measured = deskew_points(ref, s, 0.0, 1.0, se3_exp(-xi))  # each point where the moving sensor saw it
    group = np.full(len(ref), TRUNK, np.int64)
    kinds = ClassAwareConfig().kind_array()
    weights = np.ones(len(GROUP_NAMES))
    T, v, counts, _ = icp_sweep(measured, s, group, weights, kinds, 0.5, *gmap.index(), 1.0, np.eye(4), 0.6, 0.2, 100,
                                1e-7, 0.0)  # fmt: skip
    assert counts[TRUNK] > 0.9 * len(ref)
    assert np.abs(T[:2, 3]).max() < 0.01 and abs(np.degrees(np.arctan2(T[1, 0], T[0, 0]))) < 0.02
    assert abs(v[0] - 0.1) < 0.01 and abs(np.degrees(v[5]) - 2.0) < 0.2
    T0, *_ = icp(measured, group, weights, *gmap.index(), 1.0, np.eye(4), 0.6, 0.2, 100, 1e-7, kinds, 0.5)
    assert np.abs(T0[:2, 3]).max() > 0.02  # the distorted sweep registered as one rigid cloud


def test_sweep_whose_class_aware_icp_does_not_converge_is_registered_as_the_prc_variant_does():
    """A class-aware ICP at its iteration limit (here 1) costs the sweep its class-aware registration, not the
    run: the sweep is registered by KISS-ICP on the same points, kept in step; without the fallback it fails."""
    from prc_slam.odometry.classaware import IcpNotConverged

    rng = np.random.default_rng(5)
    pts, codes = _room(rng)
    keep = codes != L.TRUNK
    trunks = _stems(rng, [(5, 3), (-4, -6), (8, -9), (-7, 7)], 600)
    pts = np.concatenate([pts[keep], trunks])
    codes = np.concatenate([codes[keep], np.full(len(trunks), L.TRUNK, np.uint8)])
    config = OdometryConfig(deskew=False, max_num_iterations=1)
    odo, prc = ClassAwareOdometry(config), KissOdometry(config)
    for i, frame in enumerate(_moves(pts, 3)):
        a = odo.register(frame, None, codes, frame_time=0.1 * i)
        b = prc.register(frame, None, codes, frame_time=0.1 * i)
        np.testing.assert_allclose(a, b, atol=1e-6)
    anchored = [i for i in (1, 2) if odo.anchor_ratio[i] >= odo.config.degeneracy.ratio]
    assert anchored and odo.classaware_frames == [] and odo.unconverged_frames == anchored
    alone = ClassAwareOdometry(config, ClassAwareConfig(fallback=False))
    alone.register(pts, None, codes, frame_time=0.0)
    with pytest.raises(IcpNotConverged, match="did not converge"):
        alone.register(_moves(pts, 2)[1], None, codes, frame_time=0.1)


def test_sweep_velocity_beyond_the_guard_is_not_believed(monkeypatch):
    """A sweep registration that returns a velocity no platform has (100 rad per frame interval) is not believed:
    the frame keeps its registration from before the sweep step, exactly as without ``sweep_motion``, and is
    listed in ``sweep_rejected``; a believable one is used (``sweep_corrections``)."""
    import prc_slam.odometry.classaware as ca

    pts, codes = _room(np.random.default_rng(6))
    frames = _moves(pts, 3)

    def run(sweep_motion: bool) -> tuple[ClassAwareOdometry, list[np.ndarray]]:
        odo = ClassAwareOdometry(OdometryConfig(), ClassAwareConfig(sweep_motion=sweep_motion))
        poses = []
        for i, frame in enumerate(frames):
            times = 0.1 * i + 0.1 * np.arctan2(frame[:, 1], frame[:, 0]) / (2 * np.pi)  # one sweep, centred on 0.1 i s
            poses.append(odo.register(frame, times, codes, frame_time=0.1 * i))
        return odo, poses

    used, _ = run(True)
    assert len(used.classaware_frames) == 2 and len(used.sweep_corrections) == 2 and used.sweep_rejected == []
    _, expected = run(False)
    sweep = ca.icp_sweep

    def wild(*args):
        T, v, counts, iters = sweep(*args)
        return T, v + np.array([0, 0, 0, 0, 0, 100.0]), counts, iters

    monkeypatch.setattr(ca, "icp_sweep", wild)
    odo, poses = run(True)
    assert odo.sweep_rejected == [1, 2] and odo.sweep_corrections == []
    for a, b in zip(poses, expected, strict=True):
        np.testing.assert_array_equal(a, b)
