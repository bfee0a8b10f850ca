"""Guards, health and failure isolation of the odometry variants."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from data_tools import open_dataset
from data_tools.formats.trajectory_io import write_kitti_poses, write_tum_poses
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.config import Config, PRCConfig
from prc_slam.jobs.odometry import trajectory_file
from prc_slam.jobs.report import write_compare_outputs
from prc_slam.odometry import classaware
from prc_slam.odometry.classaware import GROUP_NAMES, ClassAwareOdometry, GroupVoxelMap, icp
from prc_slam.odometry.compare import OdometryVariants, _select, _without, run_compare
from prc_slam.odometry.guard import DivergenceMonitor, FrameHealth, GuardConfig, OdometryFailure, check_pose
from prc_slam.odometry.kiss import KissOdometry, OdometryConfig
from prc_slam.pipeline import ClassifiedFrame, classify_frames


def _translation(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    a = np.radians(yaw_deg)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[0, 3] = x
    return T


def test_check_pose_bounds():
    g = GuardConfig(max_speed=10.0, max_angular_rate=1.0)
    check_pose(_translation(0.9, 5.0), np.eye(4), 0.1, g, "x")  # 9 m/s, 0.87 rad/s
    with pytest.raises(OdometryFailure, match=r"pose jump of 1.10 m in 0.100 s"):
        check_pose(_translation(1.1), np.eye(4), 0.1, g, "x")
    with pytest.raises(OdometryFailure, match=r"pose jump of 6.0 deg"):
        check_pose(_translation(0.0, 6.0), np.eye(4), 0.1, g, "x")
    check_pose(_translation(4.0), np.eye(4), 0.5, g, "x")  # 2 Hz keyframes: 8 m/s
    bad = np.eye(4)
    bad[0, 0] = np.nan
    with pytest.raises(OdometryFailure, match="non-finite"):
        check_pose(bad, np.eye(4), 0.1, g, "x")
    with pytest.raises(OdometryFailure, match="not rigid"):
        check_pose(np.diag([2.0, 1, 1, 1]), np.eye(4), 0.1, g, "x")


def test_divergence_monitor_flags_jumps_against_the_running_level():
    mon = DivergenceMonitor(GuardConfig(divergence_factor=3.0, window=10, warm_up=3))
    flags = []
    for res, thr, inl in [(0.1, 0.5, 900), (0.12, 0.5, 950), (0.1, 0.6, 900), (0.11, 0.5, 920), (0.5, 0.5, 900)]:
        flags.append(mon.update(FrameHealth(1000, inl, res, thr)).suspicious)
    assert flags == [False, False, False, False, True]  # 0.5 > 3 x median(0.1, 0.12, 0.1, 0.11)
    h = mon.update(FrameHealth(1000, 200, 0.1, 0.5))  # inlier fraction 0.2 < 0.9 / 3
    assert h.suspicious and "inlier fraction" in h.why
    h = mon.update(FrameHealth(1000, 900, 0.1, 2.0))
    assert h.suspicious and "threshold" in h.why and "residual" not in h.why


def _room(rng, n=4000):
    g = rng.uniform([-20, -20, -1.7], [20, 20, -1.7], (n, 3))
    w1 = np.column_stack([rng.uniform(-20, 20, n), np.full(n, 15.0), rng.uniform(-1.7, 4, n)])
    w2 = np.column_stack([np.full(n, -12.0), rng.uniform(-20, 20, n), rng.uniform(-1.7, 4, n)])
    return np.concatenate([g, w1, w2]) + rng.normal(0, 0.01, (3 * n, 3))


def test_kiss_registration_returning_nan_fails_cleanly_and_never_reaches_kiss():
    pts = _room(np.random.default_rng(0))
    odo = KissOdometry(OdometryConfig(deskew=False))
    odo.register(pts)
    odo.register(pts)
    before = [p.copy() for p in odo.poses]
    real = odo.kiss.registration.align_points_to_map
    odo.kiss.registration.align_points_to_map = lambda **kw: np.full((4, 4), np.nan)
    with pytest.raises(OdometryFailure, match="non-finite pose"):
        odo.register(pts)
    assert len(odo.poses) == 2 and all(np.array_equal(a, b) for a, b in zip(odo.poses, before, strict=True))
    assert np.isfinite(odo.kiss.last_pose).all() and np.isfinite(odo.kiss.last_delta).all()  # state untouched
    odo.kiss.registration.align_points_to_map = real
    noisy = pts.copy()
    noisy[::50] = np.nan  # non-finite input points are left out, counted, and never given to KISS-ICP
    odo.register(noisy)
    assert odo.health[-1].dropped_nonfinite == len(pts[::50]) and np.isfinite(odo.poses[-1]).all()


@pytest.mark.parametrize(
    "case",
    ["too_few", "collinear", "coplanar", "one_group", "zero_weight"],
)
def test_class_aware_icp_degenerate_correspondences_give_no_nan(case):
    rng = np.random.default_rng(3)
    if case == "too_few":
        map_pts = rng.uniform(-5, 5, (5, 3))
    elif case == "collinear":
        map_pts = np.column_stack([np.linspace(-10, 10, 400), np.zeros(400), np.zeros(400)])
    else:  # a plane (the single-group cases use it too)
        map_pts = np.column_stack([rng.uniform(-10, 10, 800), rng.uniform(-10, 10, 800), np.zeros(800)])
    groups = np.full(len(map_pts), GROUP_NAMES.index("ground"))
    gmap = GroupVoxelMap(1.0, 100.0, 20)
    gmap.update(map_pts, groups, np.eye(4))
    src = map_pts + np.array([0.1, 0.05, 0.02])
    weights = np.ones(len(GROUP_NAMES))
    if case == "zero_weight":
        weights[:] = 0.0
    T, _, _, _ = icp(src, groups, weights, *gmap.index(), 1.0, np.eye(4), 3.0, 1.0, 50, 1e-4)
    assert np.isfinite(T).all()
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    if case == "coplanar":  # the constrained direction (the plane's normal) is still recovered
        assert abs(T[2, 3] + 0.02) < 0.01


def test_class_aware_odometry_on_a_single_line_does_not_return_nan():
    line = np.column_stack([np.linspace(0, 30, 3000), np.zeros(3000), np.zeros(3000)])
    odo = ClassAwareOdometry(OdometryConfig(deskew=False))
    for _ in range(3):
        pose = odo.register(line, None, np.full(len(line), L.BUILDING, np.uint8))
        assert np.isfinite(pose).all()


@pytest.fixture(scope="module")
def short_drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim") / "urban"
    write_sequence(Simulator(SimConfig(frames=12, seed=11)), root)
    return open_dataset(root)


def test_injected_failure_stops_one_variant_and_leaves_the_others_identical(short_drive, monkeypatch, tmp_path):
    # one thread where TBB lets us (KISS-ICP's parallel reductions sum in varying order); every
    # sweep matched class-aware (an urban sweep has no trunks to anchor it: it would fall back)
    cfg = Config(
        prc=PRCConfig.preset("multibeam"),
        odometry=OdometryConfig(max_num_threads=1),
        classaware=classaware.ClassAwareConfig(fallback=False),
    )
    scans = [short_drive[i] for i in range(len(short_drive))]
    clean = run_compare(iter(scans), cfg, ["raw", "prc"])
    real_icp = classaware.icp
    calls = {"n": 0}

    def nan_after_four(*args):
        calls["n"] += 1
        T, counts, partner, it = real_icp(*args)
        return (np.full((4, 4), np.nan) if calls["n"] >= 5 else T), counts, partner, it

    monkeypatch.setattr(classaware, "warm_up", lambda: None)  # count the run's ICP calls only
    monkeypatch.setattr(classaware, "icp", nan_after_four)
    res = run_compare(iter(scans), cfg, ["raw", "prc+classaware", "prc"])
    failed = res.runs["prc+classaware"].failed
    assert failed is not None and failed["frame"] == 5 and "non-finite pose" in failed["reason"]
    assert res.runs["prc+classaware"].frames == 5
    for name in ("raw", "prc"):
        assert res.runs[name].failed is None
        # identical up to the summation order of KISS-ICP's TBB reduction (bitwise when it runs alone)
        np.testing.assert_allclose(res.runs[name].poses, clean.runs[name].poses, rtol=0, atol=1e-9)
    m = res.metrics()
    json.dumps(m, allow_nan=False)  # strict JSON
    ca = m["variants"]["prc+classaware"]
    assert ca["failed"] and ca["failed_at_frame"] == 5 and ca["frames"] == 5 and ca["ate_rmse_m"] is not None
    assert m["variants"]["raw"]["frames"] == 12 and not m["variants"]["raw"]["failed"]
    assert len(m["variants"]["raw"]["per_frame"]["inliers"]) == 12
    out = tmp_path / "cmp"
    write_compare_outputs(res, cfg, out, "fault", write_kitti_poses, write_tum_poses)
    report = (out / "report.md").read_text()
    assert "**FAILED at frame 5**" in report and "prc+classaware (failed)" in report
    assert len(np.loadtxt(out / "prc+classaware_poses_kitti.txt")) == 5
    # the odometry command's TUM file of the failed variant: its 5 poses with their 5 times
    tum = trajectory_file(SimpleNamespace(result=res), "prc+classaware", out / "ca_tum.txt", "tum")
    np.testing.assert_allclose(np.loadtxt(tum)[:, 0], res.times[:5])
    assert len(np.loadtxt(out / "raw_poses_tum.txt")) == 12
    assert (out / "trajectories.png").is_file() and json.loads((out / "metrics.json").read_text())


def test_exception_inside_a_variant_is_recorded_not_raised(short_drive, monkeypatch):
    scans = [short_drive[i] for i in range(4)]

    def boom(self, *a, **k):
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(ClassAwareOdometry, "register", boom)
    res = run_compare(iter(scans), Config(prc=PRCConfig.preset("multibeam")), ["raw", "prc+classaware"])
    assert res.runs["prc+classaware"].failed == {"frame": 0, "reason": "RuntimeError: solver exploded"}
    assert res.runs["raw"].frames == 4
    m = res.metrics()["variants"]["prc+classaware"]
    assert m["frames"] == 0 and m["ms_per_frame"] is None and "ate_rmse_m" not in m


def test_health_is_recorded_per_frame(short_drive):
    res = run_compare(iter([short_drive[i] for i in range(6)]), Config(prc=PRCConfig.preset("multibeam")), ["raw"])
    health = res.runs["raw"].odometry.health
    assert len(health) == 6 and health[0].source_points == 0  # no map on the first frame
    for h in health[1:]:
        assert 0.5 < h.inlier_fraction <= 1.0 and 0 < h.mean_residual_m < h.threshold_m * 3


def test_overlap_changes_no_pose_and_charges_the_wall_time(short_drive):
    """The next frame made beside the PRC variants' registration: the same poses as one after the
    other; a PRC variant is credited at most its own filter and registration time (not its health
    residuals) and the next frame's charged PRC time, ``raw`` nothing."""
    scans = [short_drive[i] for i in range(8)]
    runs = {}
    for overlap in (False, True):
        cfg = Config(prc=PRCConfig.preset("multibeam"), odometry=OdometryConfig(max_num_threads=1, overlap=overlap))
        runs[overlap] = run_compare(iter(scans), cfg, ["prc", "raw"])
    for name in ("raw", "prc"):
        np.testing.assert_allclose(runs[True].runs[name].poses, runs[False].runs[name].poses, rtol=0, atol=1e-9)
    assert not any(runs[False].runs["prc"].hidden) and not any(runs[True].runs["raw"].hidden)
    prc = runs[True].runs["prc"]
    hidden = np.array(prc.hidden)
    busy = np.array(prc.ms["filter"]) + np.array(prc.ms["icp"])  # the health residuals hide nothing
    assert len(hidden) == 8 and (hidden >= 0).all() and (hidden <= busy + 1e-9).all() and hidden.sum() > 0
    # at most the next frame's PRC and filter and the organising of the one read ahead (none: the
    # simulator's sweeps come organised); reading is charged to no variant; nothing after the last frame
    made = np.array(prc.ms["prc"][1:]) + np.array(prc.ms["filter"][1:])
    assert (hidden[:-1] <= made + 1e-9).all() and hidden[-1] == 0.0
    np.testing.assert_allclose(prc.ms_per_frame(), prc.ms_per_frame(serial=True) - hidden)
    m = runs[True].metrics()["variants"]["prc"]
    assert m["ms_overlapped"] == pytest.approx(hidden.mean())
    assert m["ms_per_frame"] == pytest.approx(m["ms_per_frame_serial"] - hidden.mean())
    assert m["per_frame"]["ms_wall"] == pytest.approx(prc.ms_per_frame().tolist())


def test_the_filter_made_with_the_frame_chooses_what_the_variant_would(short_drive):
    """``prepare`` filters a frame as it is made (beside the registration of the frame before):
    the same points, registration order and source as the filter run at registration, its time and
    interval recorded with the frame; a frame without labels is left as it is."""
    cfg = Config(prc=PRCConfig.preset("multibeam"))
    stage = OdometryVariants(cfg, ["raw", "prc"])
    frame = next(classify_frames([short_drive[0]], cfg.prc))
    made = stage.prepare(frame)
    keep, _, res = _select("prc", frame.scan.points(), frame.point_labels(), frame, cfg)
    np.testing.assert_array_equal(made.filtered.keep, keep)
    np.testing.assert_array_equal(made.filtered.kept_in_order, res.kept_in_order)
    np.testing.assert_array_equal(made.filtered.source, res.source)
    assert made.filtered.counts_kept == res.counts_kept and 0 < keep.sum() < len(keep)
    assert made.filter_seconds > 0 and made.spans[:-1] == frame.spans
    t0, t1 = made.spans[-1]
    assert t1 - t0 == pytest.approx(made.filter_seconds)
    bare = ClassifiedFrame(short_drive[0], None, 0.0)
    assert stage.prepare(bare) is bare
    assert OdometryVariants(cfg, ["raw"]).prepare(frame) is frame  # no PRC variant: nothing to filter


def test_work_beside_the_health_residuals_is_not_credited():
    """An interval less the health checks' intervals, by hand."""
    assert _without((0.0, 10.0), []) == [(0.0, 10.0)]
    assert _without((0.0, 10.0), [(6.0, 7.0), (2.0, 3.0)]) == [(0.0, 2.0), (3.0, 6.0), (7.0, 10.0)]
    assert _without((0.0, 10.0), [(0.0, 1.0), (9.0, 10.0)]) == [(1.0, 9.0)]
    assert _without((0.0, 10.0), [(-1.0, 11.0)]) == []


@pytest.mark.parametrize("kind", ["kiss", "classaware"])
def test_a_frame_too_sparse_to_register_gets_the_predicted_pose_and_the_run_goes_on(kind):
    """A sweep cut to a handful of points (or emptied by a filter) between full ones: that frame
    takes the constant-velocity prediction, is flagged and counted, leaves the map alone, and the
    next full frame registers as usual."""
    rng = np.random.default_rng(5)
    room = _room(rng)
    step = np.array([0.5, 0.0, 0.0])
    odo = KissOdometry(OdometryConfig(deskew=False)) if kind == "kiss" else ClassAwareOdometry(OdometryConfig())
    for k in range(4):  # the sensor moves +0.5 m in x per frame: the room moves -0.5 m
        odo.register(room - k * step, None, None, float(k))
    n_map = odo.kiss.local_map.point_cloud().shape[0] if kind == "kiss" else odo.map.n
    predicted = odo.poses[-1] @ (np.linalg.inv(odo.poses[-2]) @ odo.poses[-1])
    pose = odo.register((room - 4 * step)[:12], None, None, 4.0)  # 12 points
    np.testing.assert_allclose(pose, predicted, atol=1e-12)
    assert odo.coasted == [4] and odo.health[-1].suspicious and "only" in odo.health[-1].why
    assert (odo.kiss.local_map.point_cloud().shape[0] if kind == "kiss" else odo.map.n) == n_map
    pose = odo.register(room - 5 * step, None, None, 5.0)
    assert abs(pose[0, 3] - 2.5) < 0.05 and not odo.health[-1].suspicious and len(odo.poses) == 6


def test_point_times_on_another_clock_are_named():
    """Per-point times in epoch seconds beside frame times from 0: a clear reason, not an empty
    registration after deskewing every point kilometres away."""
    rng = np.random.default_rng(3)
    pts = _room(rng)
    odo = KissOdometry(OdometryConfig())
    times = 1.7e9 + np.linspace(0.0, 0.1, len(pts))
    with pytest.raises(OdometryFailure, match=r"times lie 1\.7e\+09 s from the frame's time 0\.000000 s: not on one"):
        odo.register(pts, times, frame_time=0.0)
    ok = KissOdometry(OdometryConfig())
    ok.register(pts, np.linspace(0.0, 0.1, len(pts)), frame_time=0.05)  # one clock: registered
    assert len(ok.poses) == 1


def test_a_drifted_rotation_is_made_orthonormal_again():
    """:func:`orthonormal` projects a rotation that drifted beyond ``ORTHONORMAL_TOL`` back onto SO(3) (nearest
    rotation, translation kept) and leaves one within it alone."""
    from scipy.spatial.transform import Rotation

    from prc_slam.odometry.guard import ORTHONORMAL_TOL, orthonormal

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    T[:3, 3] = [4.0, -2.0, 0.5]
    assert orthonormal(T) is T
    drifted = T.copy()
    drifted[:3, :3] += 1e-9 * np.random.default_rng(0).normal(size=(3, 3))
    assert np.abs(drifted[:3, :3] @ drifted[:3, :3].T - np.eye(3)).max() > ORTHONORMAL_TOL
    out = orthonormal(drifted)
    R = out[:3, :3]
    assert np.abs(R @ R.T - np.eye(3)).max() < 1e-15 and np.linalg.det(R) > 0
    np.testing.assert_allclose(out, T, atol=1e-8)
    np.testing.assert_array_equal(out[:3, 3], T[:3, 3])


_DRIFTING = """
import sys
import numpy as np
from prc_slam import labels as L
from prc_slam.odometry.classaware import ClassAwareOdometry
from prc_slam.odometry.kiss import GuardedOdometry, KissOdometry, OdometryConfig

condition = GuardedOdometry._condition

def drifting(self, *args):  # the pose after the degeneracy step, its rotation drifted by 1e-9
    pose = condition(self, *args).copy()
    pose[:3, :3] *= 1 + 1e-9
    return pose

GuardedOdometry._condition = drifting
rng = np.random.default_rng(2)
pts = np.concatenate([
    rng.uniform([-20, -20, -1.7], [20, 20, -1.7], (4000, 3)),
    np.column_stack([rng.uniform(-20, 20, 2000), np.full(2000, 15.0), rng.uniform(-1.7, 4, 2000)]),
    np.column_stack([np.full(2000, -12.0), rng.uniform(-20, 20, 2000), rng.uniform(-1.7, 4, 2000)]),
])
codes = np.full(len(pts), L.BUILDING, np.uint8)
odo = (KissOdometry if sys.argv[1] == "prc" else ClassAwareOdometry)(OdometryConfig(deskew=False))
for i in range(4):
    pose = odo.register(pts - [0.3 * i, 0, 0], None, codes, frame_time=0.1 * i)
    R = pose[:3, :3]
    print(np.abs(R @ R.T - np.eye(3)).max(), pose[0, 3] - 0.3 * i)
"""


@pytest.mark.parametrize("variant", ["prc", "classaware"])
def test_poses_stay_orthonormal_when_the_registration_drifts(variant):
    """Products of poses drift from orthonormal by ~1e-16 each, and KISS-ICP's Sophus aborts the process near
    1e-10: a registration whose pose drifted by 1e-9 is stored, and the next frame registered from it, with an
    orthonormal rotation (in a child process: without the projection it aborts)."""
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", _DRIFTING, variant], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = np.array([line.split() for line in run.stdout.strip().splitlines()], float)
    assert len(rows) == 4
    assert (rows[:, 0] <= 1e-13).all() and (np.abs(rows[:, 1]) < 0.02).all()
