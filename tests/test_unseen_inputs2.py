"""More inputs the project did not read at first (after
``test_unseen_inputs.py``): each test generates a small input in ``tmp_path`` and checks that the
readers, writers and jobs either give the right result or say clearly why they cannot.

- Geo-referenced map clouds (UTM-like x ~ 5e5, y ~ 5.4e6, z ~ 300): LAS with a 1 mm scale keeps
  every coordinate and gives the labels of the same cloud at the origin; float32 coordinates that
  large (PCD, NPY, PLY) keep one value per 0.5 m, which is warned (it was classified silently).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from data_tools.formats.pcd import write_pcd

UTM = np.array([512_345.678, 5_412_345.432, 300.0])


def block_scene(n: int = 30_000, seed: int = 0) -> np.ndarray:
    """A 60 m x 60 m ground with a 20 m x 15 m x 8 m block building (roof and four walls)."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(0, 60, n), rng.uniform(0, 60, n), rng.normal(0, 0.02, n)])
    ground = ground[~((ground[:, 0] > 20) & (ground[:, 0] < 40) & (ground[:, 1] > 20) & (ground[:, 1] < 35))]
    m = n // 4
    roof = np.column_stack([rng.uniform(20, 40, m), rng.uniform(20, 35, m), 8 + rng.normal(0, 0.02, m)])
    walls = []
    for x0, x1, y0, y1 in ((20, 40, 20, 20), (20, 40, 35, 35), (20, 20, 20, 35), (40, 40, 20, 35)):
        t, h = rng.uniform(0, 1, m // 2), rng.uniform(0, 8, m // 2)
        walls.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), h]))
    return np.concatenate([ground, roof, *walls])


def write_las(path: Path, xyz: np.ndarray, scale: float = 0.001) -> Path:
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(path)
    return path


# ------------------------------------------------------------------ geo-referenced map clouds


def test_utm_las_with_a_millimetre_scale_keeps_its_geometry_and_labels(tmp_path):
    """The same cloud at the origin and at UTM coordinates: the written coordinates are the
    input's to the millimetre, and the labels agree (up to the voxel grids' other alignment)."""
    import laspy

    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz = np.round(block_scene(), 3)
    results = {}
    for name, shift in (("origin", np.zeros(3)), ("utm", UTM)):
        path = write_las(tmp_path / f"{name}.las", xyz + shift)
        metrics = mapclass_job(path, Config(), tmp_path / name)
        out = laspy.read(metrics["files"]["all"])
        written = np.column_stack([out.x, out.y, out.z]) - shift
        assert len(written) == len(xyz)
        np.testing.assert_allclose(written, xyz, atol=1.5e-3)
        results[name] = np.asarray(out.classification)
        assert (results[name] == 6).mean() > 0.3 and (results[name] == 2).mean() > 0.3  # building and ground
    assert np.mean(results["origin"] == results["utm"]) > 0.98


def _ply_float32(path: Path, xyz: np.ndarray) -> Path:
    from data_tools.formats.writers import write_ply

    write_ply(path, xyz)
    return path


def _npy(path: Path, xyz: np.ndarray) -> Path:
    np.save(path, xyz)
    return path


def _pcd(path: Path, xyz: np.ndarray) -> Path:
    write_pcd(path, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
    return path


@pytest.mark.parametrize(
    ("suffix", "writer"), [(".pcd", _pcd), (".npy", _npy), (".ply", _ply_float32)], ids=["pcd", "npy", "ply"]
)
def test_float32_utm_coordinates_are_warned(tmp_path, caplog, suffix, writer):
    """Before: float32 northings of 5.4e6 (one value per 0.5 m) were classified without a word."""
    from data_tools.formats.clouds import cloud_chunks

    xyz = block_scene(3000) + UTM
    path = writer(tmp_path / f"utm32{suffix}", xyz.astype(np.float32))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        got = np.concatenate(list(cloud_chunks(path)))
        list(cloud_chunks(path))
    assert len(got) == len(xyz)
    warned = [r.getMessage() for r in caplog.records if "stored with a step" in r.getMessage()]
    assert len(warned) == 1 and "float32" in warned[0] and "step of 0.5" in warned[0] and path.name in warned[0]


@pytest.mark.parametrize("case", ["float64 at UTM", "float32 at the origin"])
def test_fine_enough_coordinates_are_not_warned(tmp_path, caplog, case):
    from data_tools.formats.clouds import cloud_chunks

    xyz = block_scene(3000)
    if case == "float64 at UTM":
        xyz = xyz + UTM
    else:
        xyz = xyz.astype(np.float32)
    paths = [_pcd(tmp_path / "c.pcd", xyz), _npy(tmp_path / "c.npy", xyz)]
    if case == "float32 at the origin":
        paths.append(_ply_float32(tmp_path / "c.ply", xyz))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        for path in paths:
            got = np.concatenate(list(cloud_chunks(path)))
            np.testing.assert_allclose(got, np.asarray(xyz, np.float64), atol=1e-9)
    assert not [r for r in caplog.records if "stored with a step" in r.getMessage()]


# ------------------------------------------------------------------ KITTI folders holding some of the sweeps


def _kitti_folder(root: Path, numbers: list[int], n_lines: int) -> Path:
    """A KITTI layout with sweeps ``NNNNNN.bin`` for ``numbers`` and ``n_lines`` poses (pose k at
    x = k metres) and times (k x 0.1 s), an identity ``Tr``."""
    from tests.test_unseen_inputs import spinning_grid

    (root / "velodyne").mkdir(parents=True)
    for k in numbers:
        g = spinning_grid(seed=k).reshape(-1, 3)
        g = g[np.isfinite(g).all(axis=1)]
        np.column_stack([g, np.zeros(len(g), np.float32)]).astype(np.float32).tofile(root / "velodyne" / f"{k:06d}.bin")
    poses = np.tile(np.eye(4)[:3].ravel(), (n_lines, 1))
    poses[:, 3] = np.arange(n_lines)
    np.savetxt(root / "poses.txt", poses)
    np.savetxt(root / "times.txt", np.arange(n_lines) * 0.1)
    (root / "calib.txt").write_text("Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    return root


def test_kitti_sweeps_numbered_from_10_take_their_own_poses_and_times(tmp_path):
    """Before: sweeps 10, 11, 13, 14 beside the sequence's full poses.txt / times.txt took lines
    1-4 (the ground truth of other sweeps, without a word)."""
    from data_tools.formats.kitti import KittiSequence

    seq = KittiSequence(_kitti_folder(tmp_path, [10, 11, 13, 14], 16))
    np.testing.assert_allclose(seq.poses[:, 0, 3], [10, 11, 13, 14])
    np.testing.assert_allclose(seq.times, [1.0, 1.1, 1.3, 1.4])
    scan = seq[2]
    assert scan.name == "000013"
    assert scan.gt_pose[0, 3] == pytest.approx(13.0) and scan.meta["frame_time"] == pytest.approx(1.3)


def test_kitti_lines_for_exactly_the_sweeps_present_stay_in_order(tmp_path):
    from data_tools.formats.kitti import KittiSequence

    seq = KittiSequence(_kitti_folder(tmp_path, [10, 11, 13, 14], 4))
    np.testing.assert_allclose(seq.poses[:, 0, 3], [0, 1, 2, 3])
    seq = KittiSequence(_kitti_folder(tmp_path / "b", [0, 1, 2], 16))  # KITTI's own: the first lines
    np.testing.assert_allclose(seq.poses[:, 0, 3], [0, 1, 2])


def test_kitti_sweep_numbers_beyond_the_pose_file_are_an_error(tmp_path):
    from data_tools import DataError
    from data_tools.formats.kitti import KittiSequence

    with pytest.raises(DataError, match=r"times.txt: 6 times for scans numbered 000010..000014"):
        KittiSequence(_kitti_folder(tmp_path, [10, 11, 13, 14], 6))


# ------------------------------------------------------------------ --config YAML files


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("prc:\n  k: 99\n  bogus_key: 3\n", "bad.yaml: prc.bogus_key: Extra inputs are not permitted (got 3)"),
        ("prc:\n  k: many\n", "bad.yaml: prc.k: Input should be a valid integer"),
        ("mapclass:\n  ground:\n    cell: x\n", "bad.yaml: mapclass.ground.cell: Input should be a valid number"),
        ("prcc:\n  k: 99\n", "bad.yaml: prcc: Extra inputs are not permitted"),
        ("prc: [1, 2\n", "bad.yaml: cannot read config (line 2, column 1): expected ',' or ']'"),
    ],
    ids=["unknown key", "wrong type", "nested wrong type", "unknown section", "broken yaml"],
)
def test_config_errors_name_the_file_and_the_key_as_written(tmp_path, text, expected):
    """Before: ``--prc.bogus-key: ...`` (an option that does not exist, the key spelt with hyphens,
    no file) and, for broken YAML, the parser's first line without its position."""
    from typer.testing import CliRunner

    from prc_slam.cli import app
    from prc_slam.config import Config

    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        Config.from_yaml(path, Config())
    assert str(info.value).startswith(str(path)) and expected.split("bad.yaml: ")[1] in str(info.value)
    res = CliRunner().invoke(app, ["mapclass", str(tmp_path / "none.npy"), "--config", str(path)])
    assert res.exit_code == 2 and expected in " ".join(res.output.split())


# ------------------------------------------------------------------ label files that do not fit


def _with_labels(root: Path, bad: np.ndarray | None) -> None:
    """SemanticKITTI labels (road, 40) for every sweep of ``root``; sweep 1's file holds ``bad``
    (given the right count) instead."""
    (root / "labels").mkdir()
    for i, f in enumerate(sorted((root / "velodyne").glob("*.bin"))):
        n = f.stat().st_size // 16
        lab = np.full(n, 40, np.uint32) if i != 1 or bad is None else bad(n)
        lab.tofile(root / "labels" / (f.stem + ".label"))


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (lambda n: np.full(n - 3, 40, np.uint32), "labels for"),
        (lambda n: np.full(n, 40, np.uint16), "one uint16 per point? SemanticKITTI labels are uint32"),
        (lambda n: np.full(n, 40, np.uint64), "one uint64 per point? SemanticKITTI labels are uint32"),
    ],
    ids=["count", "uint16", "uint64"],
)
def test_a_label_file_that_does_not_fit_leaves_its_frame_classified(tmp_path, bad, message):
    """Before: the whole frame was skipped (no labels written for it, not registered by odometry)
    because its reference labels did not fit; now it is classified and only not scored."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    root = _kitti_folder(tmp_path / "seq", [0, 1, 2], 3)
    _with_labels(root, bad)
    res = CliRunner().invoke(app, ["classify", str(root), "--labels-out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "000001.label" in text and message in text and "this frame is not scored" in text
    assert "skipped" not in text
    for f in sorted((root / "velodyne").glob("*.bin")):
        written = np.fromfile(tmp_path / "out" / (f.stem + ".label"), np.uint32)
        assert len(written) == f.stat().st_size // 16


def test_label_files_that_are_not_semantic_kitti_are_warned(tmp_path, caplog):
    from data_tools.formats.kitti import KittiSequence

    root = _kitti_folder(tmp_path / "seq", [0, 1, 2], 3)
    _with_labels(root, lambda n: np.random.default_rng(0).integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32))
    seq = KittiSequence(root)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        seq[0]
        assert not caplog.records  # road everywhere: SemanticKITTI's
        seq[1]
    assert "000001.label" in caplog.text and "not SemanticKITTI labels?" in caplog.text


def test_a_truncated_laz_map_is_a_one_line_error(tmp_path):
    """Before: a traceback (lazrs.LazrsError from reading the file's own classes); in a batch,
    three attempts and a failed row without the file's name."""
    import laspy
    from typer.testing import CliRunner

    from prc_slam.cli import app

    xyz = block_scene(3000)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.classification = np.full(len(xyz), 2, np.uint8)
    las.write(tmp_path / "whole.laz")
    cut = tmp_path / "cut.laz"
    cut.write_bytes((tmp_path / "whole.laz").read_bytes()[:3000])
    res = CliRunner().invoke(app, ["mapclass", str(cut), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and (res.exception is None or isinstance(res.exception, SystemExit)), res.output
    assert "cut.laz: not a readable LAS file" in " ".join(res.output.split())


# ------------------------------------------------------------------ runs too short for the health checks


def test_a_run_too_short_for_the_health_checks_says_so(tmp_path):
    """Before: ``compare --stride 5`` on KITTI 00 (four keyframes) reported every variant 'ok',
    prc+classaware too, 3.8 m short of the first 4.3 m step: no check runs before frame
    ``warm_up``. Now report.md, metrics.json and the command line say that nothing was checked."""
    import json

    from typer.testing import CliRunner

    from prc_slam.cli import app
    from prc_slam.jobs.odometry import unchecked_health_note
    from prc_slam.odometry.guard import GuardConfig

    warm_up = GuardConfig().warm_up
    assert unchecked_health_note(warm_up + 1, warm_up) is None and unchecked_health_note(None, warm_up) is None
    assert "only 1 frame:" in unchecked_health_note(1, warm_up)
    root = _kitti_folder(tmp_path / "seq", [0, 1, 2], 3)
    res = CliRunner().invoke(app, ["compare", str(root), "--variants", "raw", "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert "only 3 frames: the health checks" in " ".join(res.output.split())
    assert "only 3 frames" in json.loads((tmp_path / "out" / "metrics.json").read_text())["health_note"]
    assert "**Health not checked**: only 3 frames" in (tmp_path / "out" / "report.md").read_text()


# ------------------------------------------------------------------ gaps in the frame times


def test_a_gap_in_the_frame_times_is_warned(tmp_path, caplog):
    """Before: sweeps 0-3 and 10-15 of KITTI 00 with their times.txt (0.7 s missing) ran without a
    word; the prc variant fell 4 m behind at the gap (raw coped)."""
    from data_tools.formats.kitti import KittiSequence
    from data_tools.formats.pcd import SweepFolder
    from data_tools.formats.trajectory_io import warn_time_gaps

    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        assert warn_time_gaps(np.arange(10) * 0.1, "even") == 0
        assert warn_time_gaps(np.array([0.0, 0.1, 0.2, 0.3, 5.3, 5.4, 5.5]), "gap") == 1
        assert warn_time_gaps(np.array([0.0, 0.1, 0.9]), "too short to tell") == 0
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["gap"]
    assert "5 s between frames 3 and 4 (50.0 x the median step of 0.1 s)" in caplog.records[0].getMessage()
    caplog.clear()
    root = _kitti_folder(tmp_path / "seq", [0, 1, 2, 3, 10, 11, 12], 16)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        seq = KittiSequence(root)
    assert "times.txt: 1 gap in the frame times, the largest 0.7 s between frames 3 and 4" in caplog.text
    caplog.clear()
    folder = tmp_path / "pcd"
    folder.mkdir()
    for i in range(5):
        g = seq[i].points()
        write_pcd(folder / f"{i:06d}.pcd", {"x": g[:, 0], "y": g[:, 1], "z": g[:, 2]})
    np.savetxt(folder / "times.txt", [0.0, 0.1, 0.2, 0.3, 2.0])
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        SweepFolder(folder)
    assert "times.txt: 1 gap in the frame times, the largest 1.7 s" in caplog.text


# ------------------------------------------------------------------ maps of partly labelled sequences


def test_mapclass_on_a_sequence_labelled_in_part_scores_the_labelled_frames(tmp_path):
    """Before: ``mapclass kitti00 --max-frames 8 --every 2`` (SemanticKITTI labels for frames 0-2
    only) failed with '496488 labels for 249146 reference codes'."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import map_from_dataset, mapclass_job

    root = _kitti_folder(tmp_path / "seq", [0, 1, 2, 3], 4)
    (root / "labels").mkdir()
    n0 = (root / "velodyne" / "000000.bin").stat().st_size // 16
    np.full(n0, 40, np.uint32).tofile(root / "labels" / "000000.label")  # road, frame 0 only
    metrics = mapclass_job(root, Config(), tmp_path / "out", every=2)
    n2 = (root / "velodyne" / "000002.bin").stat().st_size // 16
    assert metrics["points"] == n0 + n2 and metrics["scored_points"] == n0
    assert metrics["per_class"]["ground"]["support"] == n0

    from data_tools.formats.kitti import KittiSequence

    seq = KittiSequence(root)
    cloud = map_from_dataset(seq, 3, 1, None, prc={0: np.full(n0, 2, np.uint8)})  # frame 1 without PRC labels
    sizes = [seq[i].n_points for i in range(3)]
    assert len(cloud.attributes["prc"]) == len(cloud) == sum(sizes)
    assert cloud.attributes["prc_known"].sum() == n0 and cloud.attributes["reference_known"].sum() == n0
    assert "instance_known" not in cloud.attributes


def test_poses_whose_z_is_not_up_are_warned(tmp_path, caplog):
    """Before: ``mapclass kitti00 --poses kitti00/poses.txt`` (camera 0's frame: the car drives
    along z) stacked the sweeps 0.86 m above each other without a word: 286,816 of 496,488 points
    'building', ground F1 0.60 instead of 0.90."""
    from data_tools.formats.kitti import KittiSequence
    from prc_slam.jobs.mapclass import map_from_dataset, warn_unless_z_up

    def poses(axis: int, step: float, n: int = 6) -> np.ndarray:
        p = np.tile(np.eye(4), (n, 1, 1))
        p[:, axis, 3] = np.arange(n) * step
        return p

    with caplog.at_level(logging.WARNING, logger="prc_slam.mapclass"):
        assert warn_unless_z_up(poses(2, 0.86), "camera.txt")  # KITTI camera 0: forward is z
        assert not warn_unless_z_up(poses(0, 0.86), "lidar.txt")  # forward is x
        assert not warn_unless_z_up(poses(2, 0.1), "short.txt")  # 0.5 m of path: a lift, not a drive
        assert not warn_unless_z_up(poses(0, 0.0), "still.txt")
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["camera.txt"]
    caplog.clear()
    root = _kitti_folder(tmp_path / "seq", [0, 1, 2, 3], 4)
    np.savetxt(tmp_path / "cam.txt", poses(2, 0.86, 4)[:, :3, :].reshape(4, 12))
    with caplog.at_level(logging.WARNING, logger="prc_slam.mapclass"):
        map_from_dataset(KittiSequence(root), 4, 1, tmp_path / "cam.txt")
    assert "cam.txt: the poses climb 2.6 m and move 0.0 m horizontally" in caplog.text


# ------------------------------------------------------------------ a folder of decoded sweeps from several sensors


def test_a_folder_of_sweeps_from_several_ouster_sensors_is_warned(ouster_files, tmp_path, caplog):
    """Before: the shared decoded folder (OS-0, OS-1, OS-2) ran as one sequence; odometry stopped at
    frame 1 on a frame time going back, with no word about the cause."""
    import shutil

    from data_tools.formats.ouster import OusterSequence

    def one(prefix: str) -> Path:
        found = [f for f in ouster_files if f.name.startswith(prefix)]
        if not found:
            pytest.skip(f"no shared Ouster sweep {prefix}*")
        return found[0]

    same, mixed = tmp_path / "same", tmp_path / "mixed"
    for folder, prefixes in (
        (same, ["OS-1-128_lb_n3_frame0", "OS-1-128_lb_n3_frame1"]),
        (mixed, ["OS-1-128_lb_n3_frame0", "OS-2-128"]),
    ):
        folder.mkdir()
        for k, prefix in enumerate(prefixes):
            shutil.copy(one(prefix), folder / f"{k:06d}.npz")
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        seq = OusterSequence(same)
        [seq[i] for i in range(len(seq))]
        assert not caplog.records
        seq = OusterSequence(mixed)
        [seq[i] for i in range(len(seq))]
        seq[1]
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "000001.npz: its beam table" in warned[0] and "mixes sensors" in warned[0]


# ------------------------------------------------------------------ sweeps in a world frame


def test_sweeps_in_a_world_frame_are_told_apart_from_millimetres(tmp_path, caplog):
    """Before: a sweep written in UTM coordinates was warned as 'not in metres (millimetres?
    centimetres?)', which sends the user to convert units that are right."""
    import contextlib

    from data_tools import DataError
    from data_tools.formats.pcd import SweepFolder
    from prc_slam.scan import ScanError
    from tests.test_unseen_inputs import spinning_grid

    g = spinning_grid().reshape(-1, 3).astype(np.float64)
    g = g[np.isfinite(g).all(axis=1)]
    for name, xyz in (("utm", g + UTM), ("local", g + np.array([400.0, -150.0, 2.0])), ("mm", g * 1000.0), ("m", g)):
        folder = tmp_path / name
        folder.mkdir()
        write_pcd(folder / "000000.pcd", {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
            with contextlib.suppress(DataError, ScanError):  # the organiser may refuse it: the warning is tested
                SweepFolder(folder)[0]
        text = caplog.text
        if name in ("utm", "local"):
            assert "in a world or map frame, not their sensor's" in text and "millimetres" not in text
        else:
            assert ("not in metres (millimetres?" in text) == (name == "mm") and "world or map frame" not in text


def test_a_recording_of_registered_clouds_is_warned(tmp_path, caplog):
    """A bag topic of clouds already in the map frame (FAST-LIO's ``/cloud_registered``, 300 m
    from the origin) was organised without a word about the frame."""
    import contextlib

    from data_tools import DataError
    from data_tools.formats.rosbag import RosbagSequence, cloud_from_records
    from data_tools.formats.stream_out import RosCloudWriter
    from tests.test_unseen_inputs import spinning_grid

    g = spinning_grid().reshape(-1, 3)
    g = g[np.isfinite(g).all(axis=1)]
    for name, offset, frame in (("map", (300.0, -120.0, 5.0), "camera_init"), ("sensor", (0.0, 0.0, 0.0), "lidar")):
        rec = np.zeros(len(g), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
        for k, c in enumerate("xyz"):
            rec[c] = g[:, k] + offset[k]
        with RosCloudWriter(tmp_path / f"{name}.mcap", "mcap", "/cloud") as w:
            for i in range(2):
                w.write_cloud(cloud_from_records(rec, frame_id=frame, stamp_ns=(i + 1) * 100_000_000, seq=i))
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
            with RosbagSequence(tmp_path / f"{name}.mcap") as seq:
                for i in range(2):
                    with contextlib.suppress(DataError):  # the organiser may refuse it: the warning is tested
                        seq[i]
        warned = [r.getMessage() for r in caplog.records if "world or map frame" in r.getMessage()]
        assert len(warned) == (name == "map")
        if warned:
            assert "frame 'camera_init'" in warned[0] and "/cloud" in warned[0]


UTM32N_WKT = (
    'PROJCS["WGS 84 / UTM zone 32N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
    'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
    'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",9],PARAMETER["scale_factor",0.9996],'
    'PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1],AUTHORITY["EPSG","32632"]]'
)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_the_classified_clouds_keep_the_input_crs(tmp_path, suffix):
    """Before: a UTM tile with its WKT CRS came out as LAS files without one (a GIS placed the
    classified clouds nowhere)."""
    import laspy
    from laspy.vlrs.known import WktCoordinateSystemVlr

    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz = np.round(block_scene(6000), 3) + UTM
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.floor(xyz.min(axis=0))
    header.vlrs.append(WktCoordinateSystemVlr(UTM32N_WKT))
    header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(tmp_path / f"tile{suffix}")
    plain = write_las(tmp_path / "plain.las", xyz)
    metrics = mapclass_job(tmp_path / f"tile{suffix}", Config(), tmp_path / "out", laz=suffix == ".laz")
    assert len(metrics["files"]) > 2
    for path in metrics["files"].values():
        out = laspy.read(path)
        wkt = [v for v in out.header.vlrs if isinstance(v, WktCoordinateSystemVlr)]
        assert len(wkt) == 1 and "UTM zone 32N" in wkt[0].string and out.header.global_encoding.wkt
    metrics = mapclass_job(plain, Config(), tmp_path / "plain")
    assert not laspy.read(metrics["files"]["all"]).header.vlrs
