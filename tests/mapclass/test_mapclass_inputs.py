"""What ``mapclass`` accepts: a sequence labelled in part, TUM poses, one cloud file (not a folder of
tiles, not an unknown file, not with sequence options) and a tile's own classes and instances.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from tests.inputs.kitti import kitti_folder
from tests.inputs.las import ground_and_wall, write_las
from tests.inputs.poses import yaw_poses


def test_mapclass_on_a_sequence_labelled_in_part_scores_the_labelled_frames(tmp_path):
    """``mapclass kitti00 --max-frames 8 --every 2`` with SemanticKITTI labels for frames 0-2 only scores the
    points of the labelled frames (no mismatch between label and point counts)."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import map_from_dataset, mapclass_job

    root = kitti_folder(tmp_path / "seq", [0, 1, 2, 3], 4)
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


laspy = pytest.importorskip("laspy")


def test_mapclass_takes_tum_poses_like_kitti_poses_and_warns_of_extra_poses(tmp_path, caplog):

    from data_tools.formats.kitti import KittiSequence
    from data_tools.formats.trajectory_io import write_kitti_poses, write_tum_poses
    from prc_slam.jobs.mapclass import map_from_dataset
    from tests.inputs.kitti import make_kitti

    root = make_kitti(tmp_path / "seq", frames=4, labels=False)
    seq = KittiSequence(root)
    poses = yaw_poses(4)
    write_kitti_poses(tmp_path / "p.kitti", poses)
    write_tum_poses(tmp_path / "p.tum", np.asarray(seq.times), poses)
    write_kitti_poses(tmp_path / "more.kitti", yaw_poses(9))
    a = map_from_dataset(seq, 4, 1, tmp_path / "p.kitti")
    b = map_from_dataset(seq, 4, 1, tmp_path / "p.tum")
    np.testing.assert_allclose(a.points, b.points, atol=1e-6)
    with caplog.at_level(logging.WARNING, logger="prc_slam.mapclass"):
        c = map_from_dataset(seq, 4, 1, tmp_path / "more.kitti")
    np.testing.assert_allclose(a.points, c.points, atol=1e-6)
    assert "more.kitti: 9 poses for 4 frames: the first 4 are used" in caplog.text


def test_a_folder_of_las_tiles_given_to_mapclass_says_to_give_one_cloud(tmp_path):
    """A folder of LAS tiles given to ``mapclass`` is a one-line error that asks for one cloud file."""
    from data_tools.errors import DataError
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = ground_and_wall(300)
    (tmp_path / "tiles").mkdir()
    write_las(tmp_path / "tiles" / "a.las", xyz, classes)
    write_las(tmp_path / "tiles" / "b.las", xyz + 50, classes)
    with pytest.raises(DataError, match="a folder of 2 LAS/LAZ files: mapclass classifies one cloud file"):
        mapclass_job(tmp_path / "tiles", Config(), tmp_path / "out")


def test_an_unknown_file_given_to_mapclass_lists_the_cloud_formats(tmp_path):
    """An unknown file given to ``mapclass`` is an error that lists the cloud formats it reads (LAS/LAZ, PLY,
    NPY, NPZ) besides the sequence formats."""
    from data_tools.errors import DataError
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    (tmp_path / "cloud.xyz").write_text("x y z\n1 2 3\n")
    with pytest.raises(
        DataError, match=r"cloud.xyz: unknown cloud format '.xyz': mapclass reads one cloud file \(.las"
    ):
        mapclass_job(tmp_path / "cloud.xyz", Config(), tmp_path / "out")


def test_reference_classes_without_a_map_class_are_warned_with_their_counts(tmp_path, caplog):
    """Reference classes without a map class (ASPRS water 9, bridge deck 17, a producer's own class 40) are
    warned with their point counts, since each such point scores as a false positive; standard classes with a
    counterpart (2, 3-6, 11, 20) are not warned of."""

    from prc_slam.jobs.mapclass import warn_unscored_reference

    ref = np.array([2] * 10 + [9] * 3 + [17] * 2 + [40] + [3, 4, 5, 6, 11, 20, 18, 7, 1, 0], np.uint8)
    with caplog.at_level(logging.WARNING, logger="prc_slam.mapclass"):
        assert warn_unscored_reference(Path("t.las"), ref) == [9, 17, 40]
        assert warn_unscored_reference(Path("u.las"), np.delete(ref, np.isin(ref, (9, 17, 40)).nonzero())) == []
    assert caplog.text.count("no class for") == 1
    assert "9 (water: 3 points), 17 (bridge deck: 2 points), 40 (user or reserved: 1 points)" in caplog.text


def test_a_tiles_own_classes_and_instances_are_read_chunk_by_chunk(tmp_path, monkeypatch):
    """``cloud_classes`` reads classification, instance and withheld chunk by chunk (laspy.read
    held every dimension of every point: 30-40 bytes a point for a tile scored against itself);
    the result is that of reading the whole file, over several chunks."""
    import data_tools.formats.clouds as clouds

    xyz, classes = ground_and_wall(900)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dim(laspy.ExtraBytesParams("instance", np.uint32))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.classification = classes
    las.instance = np.arange(len(xyz), dtype=np.uint32) * 7
    las.withheld = np.arange(len(xyz)) % 3 == 0
    las.write(tmp_path / "tile.laz")
    real = laspy.LasReader.chunk_iterator
    monkeypatch.setattr(laspy.LasReader, "chunk_iterator", lambda self, size: real(self, 250))
    codes, inst, scored = clouds.cloud_classes(tmp_path / "tile.laz")
    np.testing.assert_array_equal(codes, classes)
    np.testing.assert_array_equal(inst, np.arange(len(xyz)) * 7)
    np.testing.assert_array_equal(scored, np.arange(len(xyz)) % 3 != 0)


def test_sequence_options_given_with_one_cloud_file_are_an_error(tmp_path):
    """``mapclass map.las --poses p.txt --every 3``: options of a sequence given with one cloud file are an
    error, not ignored."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    xyz, classes = ground_and_wall(300)
    write_las(tmp_path / "map.las", xyz, classes)
    out = str(tmp_path / "out")
    cases = [
        (["--poses", str(tmp_path / "p.txt"), "--every", "3"], "--poses, --every: for a sequence of sweeps"),
        (["--rows", "64"], "--rows: for a sequence of sweeps"),
    ]
    for args, needle in cases:
        res = CliRunner().invoke(app, ["mapclass", str(tmp_path / "map.las"), "--out", out, *args])
        assert res.exit_code != 0 and needle in res.output and "map.las is one cloud" in res.output, res.output
        assert not (tmp_path / "out" / "map_classified.las").exists()
