"""Filter policy, KISS-ICP adapter, variant comparison, trajectory regression (golden files)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import NoiseConfig, SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.cli import app
from prc_slam.config import Config, PRCConfig
from prc_slam.filtering import FilterConfig, filter_points
from prc_slam.odometry.compare import run_compare
from prc_slam.odometry.kiss import KissOdometry, OdometryConfig, kiss_config
from prc_slam.testing import assert_trajectory_close

pytest_plugins = ["pytester"]


@pytest.fixture(scope="module")
def short_drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim") / "urban"
    write_sequence(Simulator(SimConfig(frames=30, seed=5, noise=NoiseConfig(outlier_rate=0.02))), root)
    return open_dataset(root)


def test_filter_drops_noise_thins_ground_keeps_the_rest():
    pts = np.array([[0.1, 0.1, 0], [0.5, 0.5, 0], [1.5, 0.2, 0], [0.2, 0.3, 1], [5, 5, 5], [6, 6, 6]], float)
    lab = np.array([L.GROUND, L.GROUND, L.GROUND, L.BUILDING, L.NOISE, L.NOISE], np.uint8)
    res = filter_points(pts, lab, FilterConfig(cell=1.0, representative="first"))
    assert res.keep.tolist() == [True, False, True, True, False, False]  # first ground point per 1 m cell
    assert res.kept_in_order.tolist() == [0, 2, 3]  # in input order
    assert res.counts_in == {"ground": 3, "building": 1, "noise": 2}
    assert res.counts_kept == {"ground": 2, "building": 1, "noise": 0}
    spared = filter_points(pts, lab, FilterConfig(), one_sided=np.array([0, 0, 0, 0, 1, 0], bool))
    assert spared.keep[4] and not spared.keep[5]
    strict = filter_points(pts, lab, FilterConfig(keep_one_sided=False), one_sided=np.array([0, 0, 0, 0, 1, 0], bool))
    assert not strict.keep[4]
    with pytest.raises(ValueError, match="do not match"):
        filter_points(pts, lab[:3], FilterConfig())


def test_filter_samples_classes_on_3d_cells_and_chooses_the_source():
    pts = np.array(
        [
            [0.1, 0.1, 0.1],  # building, cell (0, 0, 0)
            [0.3, 0.2, 0.4],  # building, same 0.5 m cell: sampled away
            [0.3, 0.2, 0.6],  # building, cell (0, 0, 1)
            [0.2, 0.2, 0.2],  # vegetation, same cell as the first but another class: kept
            [0.1, 0.1, 0.0],  # ground, 2-D cell (0, 0)
            [2.5, 0.1, 0.0],  # ground, 2-D cell (0, 0) of 3 m: thinned away
            [4.0, 0.1, 0.0],  # ground, 2-D cell (1, 0)
            [0.2, 0.1, 0.1],  # noise, one-sided: spared, never sampled
        ]
    )
    lab = np.array([L.BUILDING] * 3 + [L.VEGETATION] + [L.GROUND] * 3 + [L.NOISE], np.uint8)
    one = np.zeros(8, bool)
    one[7] = True
    cfg = FilterConfig(cell=3.0, sample={}, sample_other=0.5, source_cell={}, source_exclude=[], representative="first")
    res = filter_points(pts, lab, cfg, one)
    assert res.keep.tolist() == [True, False, True, True, True, False, True, True] and res.source is None
    src = filter_points(
        pts, lab, cfg.model_copy(update={"source_cell": {"ground": 6.0}, "source_exclude": ["vegetation"]}), one
    )
    assert np.array_equal(src.keep, res.keep)  # the map keeps the same points
    assert src.source.tolist() == [True, False, True, False, True, False, False, True]
    assert not (src.source & ~src.keep).any()
    with pytest.raises(ValueError, match="unknown class 'leaves'"):
        filter_points(pts, lab, FilterConfig(sample={"leaves": 1.0}))


def _splitmix64(i: int) -> int:
    m = (1 << 64) - 1
    z = (i + 0x9E3779B97F4A7C15) & m
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & m
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & m
    return z ^ (z >> 31)


def test_filter_random_representative_is_the_lowest_hash_of_each_cell():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-2, 2, (600, 3))
    lab = rng.choice(np.array([L.GROUND, L.BUILDING, L.NOISE], np.uint8), 600)
    cfg = FilterConfig(cell=1.0, sample={}, sample_other=1.0, source_cell={})
    assert cfg.representative == "random"  # the default
    res = filter_points(pts, lab, cfg)
    best: dict[tuple, int] = {}
    for i, (p, c) in enumerate(zip(pts, lab, strict=True)):
        if c == L.NOISE:
            continue
        cell = (int(c), *np.floor(p[:2]).astype(int), 0 if c == L.GROUND else int(np.floor(p[2])))
        if cell not in best or _splitmix64(i) < _splitmix64(best[cell]):
            best[cell] = i
    assert np.flatnonzero(res.keep).tolist() == sorted(best.values())
    order = res.kept_in_order  # every kept point once, by the top 16 bits of the hash
    assert sorted(order.tolist()) == sorted(best.values())
    top = [_splitmix64(int(i)) >> 48 for i in order]
    assert top == sorted(top)
    # not the sensor's first point: on a line of 10 points per cell, the kept one moves around
    line = np.c_[np.arange(1000) * 0.1 + 0.05, np.zeros(1000), np.zeros(1000)]
    kept = np.flatnonzero(filter_points(line, np.full(1000, L.GROUND, np.uint8), cfg).keep)
    assert len(kept) == 100 and len(set((kept % 10).tolist())) == 10


def test_filter_with_more_cells_than_its_first_table_keeps_every_cell():
    rng = np.random.default_rng(4)
    pts = rng.uniform(-100, 100, (5000, 3))  # every point in a cell of its own
    lab = np.full(5000, L.BUILDING, np.uint8)
    res = filter_points(pts, lab, FilterConfig(sample_other=0.01, source_cell={}))
    assert res.keep.all() and res.counts_kept == {"building": 5000}
    assert sorted(res.kept_in_order.tolist()) == list(range(5000))


def test_partial_yaml_config_changes_only_its_keys(tmp_path):
    base = Config(prc=PRCConfig.preset("multibeam"))
    path = tmp_path / "c.yaml"
    path.write_text("filter: {cell: 3.0}\n")  # (not the default)
    cfg = Config.from_yaml(path, base)
    assert base.filter.cell != 3.0 and cfg.prc == base.prc and cfg.filter.cell == 3.0
    assert cfg.filter.source_cell == base.filter.source_cell
    path.write_text("filter: {source_cell: {}}\n")  # a key given replaces the base's value whole
    assert Config.from_yaml(path, base).filter.source_cell == {}
    assert Config.from_yaml(path).prc == Config().prc  # without a base: the defaults


@pytest.mark.parametrize("frames", [1, 2])
def test_plot_of_a_run_too_short_to_align_warns_nothing(short_drive, tmp_path, frames):
    """One or two frames: nothing to align for the error plot, and no matplotlib warning."""
    import warnings

    from prc_slam.jobs.report import plot_trajectories

    result = run_compare([short_drive[i] for i in range(frames)], Config(), ["raw"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_trajectories(result, tmp_path / "t.png")
    assert (tmp_path / "t.png").stat().st_size > 0


def test_kiss_config_ignores_environment(monkeypatch):
    monkeypatch.setenv("kiss_icp_data__max_range", "7")
    monkeypatch.setenv("KISS_ICP_MAPPING__VOXEL_SIZE", "9")
    cfg = kiss_config(OdometryConfig())
    assert cfg.data.max_range == 100.0 and cfg.mapping.voxel_size == 1.0
    import os

    assert os.environ["kiss_icp_data__max_range"] == "7"  # restored


def test_two_frame_known_motion_is_recovered(short_drive):
    pts = short_drive[10].points().astype(np.float64)
    c, s = np.cos(np.radians(2.0)), np.sin(np.radians(2.0))
    motion = np.array([[c, -s, 0, 0.5], [s, c, 0, -0.1], [0, 0, 1, 0.02], [0, 0, 0, 1.0]])
    moved = (pts - motion[:3, 3]) @ motion[:3, :3]  # the same scene seen from the moved sensor
    odo = KissOdometry(OdometryConfig(deskew=False))
    odo.register(pts)
    pose = odo.register(moved)
    assert np.linalg.norm(pose[:3, 3] - motion[:3, 3]) < 0.01
    assert np.degrees(np.arccos(np.clip((np.trace(pose[:3, :3].T @ motion[:3, :3]) - 1) / 2, -1, 1))) < 0.05
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        odo.register(np.zeros((4, 2)))


def test_compare_metrics_schema_and_no_ground_truth(short_drive):
    scans = [short_drive[i] for i in range(8)]
    res = run_compare(scans, Config(prc=PRCConfig.preset("multibeam")))
    m = res.metrics()["variants"]
    for name in ("raw", "prc"):
        assert {
            "ate_rmse_m",
            "rpe_trans_m",
            "kitti_trans_pct",
            "ms_per_frame",
            "points_in",
            "points_to_icp",
            "frames",
        } <= set(m[name])
    assert m["prc"]["points_to_icp"] < m["raw"]["points_to_icp"] == m["raw"]["points_in"]
    assert m["prc"]["points_kept_per_class"]["ground"] < m["prc"]["points_in_per_class"]["ground"]
    for s in scans:
        s.gt_pose = None
    m2 = run_compare(scans, Config(), ["raw"]).metrics()["variants"]["raw"]
    assert "ate_rmse_m" not in m2 and m2["frames"] == 8
    with pytest.raises(ValueError, match="unknown variants"):
        run_compare(scans, Config(), ["magic"])


def test_compare_metrics_say_degenerate_frames_and_classaware_sweeps(short_drive):
    """An urban drive: no direction degenerate, and no trunk to anchor class-aware matching, so
    prc+classaware registers every sweep as prc does (the same poses, the same frames given the
    ground refinement: every one once the ground model's cells hold enough points); raw gives no
    labels, so it has no ground refinement to report."""
    scans = [short_drive[i] for i in range(8)]
    cfg = Config(prc=PRCConfig.preset("multibeam"), odometry=OdometryConfig(max_num_threads=1))
    m = run_compare(scans, cfg, ["raw", "prc", "prc+classaware"]).metrics()["variants"]
    for v in m.values():
        assert v["degenerate_frames"] == []
        ratios = v["per_frame"]["degeneracy_ratio"]
        assert ratios[0] is None and all(0 < r <= 1 for r in ratios[1:])  # no map before the first frame
    assert m["prc+classaware"]["classaware_frames"] == []
    assert abs(m["prc+classaware"]["ate_rmse_m"] - m["prc"]["ate_rmse_m"]) < 1e-6
    refined = m["prc"]["ground_refined_frames"]
    assert refined == m["prc+classaware"]["ground_refined_frames"]
    # a ground cell needs ground.min_points (5) points, and the filter gives it about one a frame
    assert 1 <= refined[0] <= 5 and refined == list(range(refined[0], 8))
    assert "ground_refined_frames" not in m["raw"]


@pytest.mark.parametrize("variant", ["raw", "prc"])
def test_golden_urban_drive(short_drive, trajectory_regression, variant):
    res = run_compare(iter(short_drive), Config(prc=PRCConfig.preset("multibeam")), [variant])
    est = res.estimate_in_world(variant)
    assert_trajectory_close(est, short_drive.poses, ate_tol=0.3, rpe_tol=0.3)  # follows the ground truth
    trajectory_regression.check(est, ate_tol=0.02, rpe_tol=0.02)  # and has not changed


def test_assert_trajectory_close_message():
    ref = np.tile(np.eye(4), (20, 1, 1))
    ref[:, 0, 3] = np.arange(20)
    est = ref.copy()
    est[12:, 1, 3] += 0.5
    with pytest.raises(AssertionError) as err:
        assert_trajectory_close(est, ref, ate_tol=0.05, rpe_tol=0.1)
    text = str(err.value)
    assert "ATE RMSE" in text and "frames 11 and 12" in text and "first frame over tolerance" in text
    assert_trajectory_close(est, ref, ate_tol=1.0, rpe_tol=1.0)
    with pytest.raises(AssertionError, match="lengths differ"):
        assert_trajectory_close(est[:5], ref, 1, 1)


def test_plugin_update_golden_cycle(pytester):
    pytester.makepyfile(
        """
        import numpy as np

        def test_walk(trajectory_regression):
            poses = np.tile(np.eye(4), (5, 1, 1))
            poses[:, 0, 3] = np.arange(5) * 1.0
            trajectory_regression.check(poses, ate_tol=0.01, rpe_tol=0.01)
        """
    )
    first = pytester.runpytest()
    first.assert_outcomes(failed=1)
    assert "--update-golden" in first.stdout.str()
    pytester.runpytest("--update-golden").assert_outcomes(passed=1)
    assert (pytester.path / "golden" / "test_walk.txt").is_file()
    pytester.runpytest().assert_outcomes(passed=1)


def test_cli_compare_and_odometry(short_drive, tmp_path):
    runner = CliRunner()
    root = str(short_drive.root)
    res = runner.invoke(app, ["compare", root, "--out", str(tmp_path / "cmp"), "--max-frames", "10"])
    assert res.exit_code == 0, res.output
    for f in (
        "report.md",
        "metrics.json",
        "config.yaml",
        "trajectories.png",
        "raw_poses_kitti.txt",
        "prc_poses_tum.txt",
        "ground_truth_poses_kitti.txt",
    ):
        assert (tmp_path / "cmp" / f).is_file(), f
    m = json.loads((tmp_path / "cmp" / "metrics.json").read_text())
    assert set(m["variants"]) == {"raw", "prc"}
    res = runner.invoke(
        app,
        [
            "odometry",
            root,
            "--filter",
            "none",
            "--max-frames",
            "5",
            "--poses-out",
            str(tmp_path / "p.txt"),
            "--pose-format",
            "tum",
            "--json",
            str(tmp_path / "o.json"),
        ],
    )
    assert res.exit_code == 0, res.output
    assert len(np.loadtxt(tmp_path / "p.txt")) == 5
    assert list(json.loads((tmp_path / "o.json").read_text())["variants"]) == ["raw"]


def test_compare_with_a_skipped_frame_says_which_frame_each_line_is(short_drive, tmp_path):
    """A frame that cannot be read is skipped: the KITTI-format trajectories (one line per
    registered frame, no times) are then shorter than the input, so ``frames.txt`` names the input
    frame of each line and report.md lists the skip."""
    import shutil

    root = tmp_path / "seq"
    shutil.copytree(short_drive.root, root)
    (root / "frames" / "000002.npz").write_bytes(b"PK\x03\x04 cut short")
    out = tmp_path / "cmp"
    res = CliRunner().invoke(app, ["compare", str(root), "--out", str(out), "--max-frames", "6"])
    assert res.exit_code == 0, res.output
    lines = [ln.split(maxsplit=2) for ln in (out / "frames.txt").read_text().splitlines() if not ln.startswith("#")]
    assert [int(ln[0]) for ln in lines] == list(range(5))
    assert [ln[2] for ln in lines] == ["000000", "000001", "000003", "000004", "000005"]
    times = np.loadtxt(root / "times.txt")
    np.testing.assert_allclose([float(ln[1]) for ln in lines], times[[0, 1, 3, 4, 5]], atol=1e-6)
    for name in ("raw", "prc", "ground_truth"):
        assert len(np.loadtxt(out / f"{name}_poses_kitti.txt")) == 5
    said = res.output.replace("\n", "")
    assert all(f"{name}_poses_{fmt}.txt" in said for name in ("raw", "prc", "ground_truth") for fmt in ("kitti", "tum"))
    report = (out / "report.md").read_text()
    assert "## Skipped frames (1)" in report and "input frame 2" in report and "000002.npz" in report


def test_kiss_threads_from_the_environment(monkeypatch):
    """KISS-ICP's thread count: the config's when set, else PRC_SLAM_THREADS (a positive
    integer; anything else means KISS-ICP's own choice, 0)."""
    from prc_slam.odometry.kiss import OdometryConfig, kiss_config

    for value, expected in (("3", 3), ("0", 0), ("-2", 0), ("two", 0), ("", 0)):
        monkeypatch.setenv("PRC_SLAM_THREADS", value)
        assert kiss_config(OdometryConfig()).registration.max_num_threads == expected
    monkeypatch.setenv("PRC_SLAM_THREADS", "3")
    assert kiss_config(OdometryConfig(max_num_threads=2)).registration.max_num_threads == 2
