"""More inputs the project did not read at first (after
``test_unseen_inputs.py`` .. ``test_unseen_inputs3.py``): each test generates a small input in
``tmp_path`` and checks that the readers, writers and jobs either give the right result or say
clearly why they cannot.

- LAS/LAZ maps: the classified clouds keep the input's scale and offsets (a 0.1 mm tile was
  written at 1 mm: every point moved by up to 0.5 mm); points the LAS 1.4 flags mark withheld
  (to be treated as deleted) are classified and written but not scored; ASPRS road surface (11)
  and ignored ground (20) in a tile's own classes are scored as ground.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")


def block_scene(n: int = 6000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 40 m x 40 m ground (ASPRS 2) with a 20 m wall 8 m high (ASPRS 6): points, classes."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(0, 40, n), rng.uniform(0, 40, n), rng.normal(0, 0.02, n)])
    m = n // 3
    wall = np.column_stack([rng.uniform(10, 30, m), np.full(m, 30.0) + rng.normal(0, 0.02, m), rng.uniform(0, 8, m)])
    return np.concatenate([ground, wall]), np.concatenate([np.full(n, 2), np.full(m, 6)]).astype(np.uint8)


def write_las(
    path: Path,
    xyz: np.ndarray,
    classes: np.ndarray | None = None,
    *,
    scale: float = 0.001,
    offset: np.ndarray | None = None,
    point_format: int = 6,
    withheld: np.ndarray | None = None,
) -> Path:
    version = "1.4" if point_format >= 6 else "1.2"
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(xyz.min(axis=0)) if offset is None else offset
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    if classes is not None:
        las.classification = classes
    if withheld is not None:
        las.withheld = withheld
    las.write(path)
    return path


# ------------------------------------------------------------------ LAS/LAZ maps


@pytest.mark.parametrize("scale", [0.0001, 0.01])
def test_the_classified_clouds_keep_the_input_scale_and_offsets(tmp_path, scale):
    """Before: every output was written at 1 mm from its own offset, whatever the input's grid; a
    0.1 mm UTM tile came out moved by up to 0.5 mm, and a 1 cm one on another grid than its own."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = block_scene()
    offset = np.array([500_000.0, 5_400_000.0, 100.0])
    xyz = xyz + np.array([500_123.4567, 5_400_321.1234, 120.0])
    src = laspy.read(write_las(tmp_path / "tile.las", xyz, classes, scale=scale, offset=offset))
    metrics = mapclass_job(tmp_path / "tile.las", Config(), tmp_path / "out")
    out = laspy.read(metrics["files"]["all"])
    assert np.allclose(out.header.scales, scale) and np.allclose(out.header.offsets, offset)
    assert np.array_equal(np.asarray(out.X), np.asarray(src.X))  # the stored integers, point for point
    assert np.array_equal(np.asarray(out.Y), np.asarray(src.Y)) and np.array_equal(np.asarray(out.Z), np.asarray(src.Z))
    parts = [laspy.read(p) for k, p in metrics["files"].items() if k != "all"]
    assert sum(len(p) for p in parts) == len(src)
    for part in parts:
        assert np.allclose(part.header.scales, scale)


def test_withheld_points_are_written_but_not_scored(tmp_path):
    """Before: the withheld flag (LAS 1.4: treat as deleted) was ignored and withheld points were
    scored like any other; now they are classified and written (one label per point) and the
    scores count the others (``scored_points``)."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = block_scene()
    withheld = np.arange(len(xyz)) % 5 == 0
    wrong = classes.copy()
    wrong[withheld] = 6  # withheld ground points carry a wrong class: they must not count
    write_las(tmp_path / "tile.las", xyz, wrong, withheld=withheld)
    write_las(tmp_path / "clean.las", xyz[~withheld], classes[~withheld])
    metrics = mapclass_job(tmp_path / "tile.las", Config(), tmp_path / "out")
    assert metrics["points"] == len(xyz) and len(laspy.read(metrics["files"]["all"])) == len(xyz)
    assert metrics["scored_points"] == int((~withheld).sum())
    support = {k: v["support"] for k, v in metrics["per_class"].items()}
    assert support["ground"] == int(((classes == 2) & ~withheld).sum())
    assert support["building"] == int(((classes == 6) & ~withheld).sum())
    plain = mapclass_job(tmp_path / "tile.las", Config(), tmp_path / "plain", reference=True)
    assert plain["scored_points"] == metrics["scored_points"]


def test_asprs_road_surface_and_ignored_ground_are_scored_as_ground(tmp_path):
    """Before: a tile whose ground carried ASPRS 11 (road surface) or 20 (ignored ground) had no
    ground in its reference (ground recall undefined, every ground point a false positive)."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = block_scene()
    coded = classes.copy()
    ground = np.flatnonzero(classes == 2)
    coded[ground[::2]] = 11
    coded[ground[1::2]] = 20
    write_las(tmp_path / "asprs.las", xyz, coded)
    write_las(tmp_path / "plain.las", xyz, classes)
    a = mapclass_job(tmp_path / "asprs.las", Config(), tmp_path / "a")
    b = mapclass_job(tmp_path / "plain.las", Config(), tmp_path / "b")
    assert a["per_class"] == b["per_class"]
    assert a["per_class"]["ground"]["support"] == len(ground)


# ------------------------------------------------------------------ NumPy clouds


def _numpy_variants(xyz: np.ndarray) -> dict[str, object]:
    n = len(xyz)
    rng = np.random.default_rng(3)
    structured = np.zeros(n, [("x", "<f8"), ("intensity", "<f4"), ("y", "<f8"), ("z", "<f8")])
    structured["x"], structured["y"], structured["z"] = xyz.T
    return {
        "n4.npy": np.column_stack([xyz, rng.random(n)]),
        "n6.npy": np.column_stack([xyz, np.tile([0.0, 0.0, 1.0], (n, 1))]),
        "structured.npy": structured,
        "alone.npz": {"anything": xyz},
        "named.npz": {"points": np.column_stack([xyz, rng.random(n)]), "intensity": rng.random(n)},
    }


@pytest.mark.parametrize("name", ["n4.npy", "n6.npy", "structured.npy", "alone.npz", "named.npz"])
def test_numpy_clouds_with_more_columns_fields_or_in_an_npz_are_read(tmp_path, name):
    """Before: ``(N, 4)`` / ``(N, 6)`` arrays and structured ones were refused ('expected (N, 3)'),
    and an ``.npz`` cloud was opened as an Ouster sweep ('the input has no ground-truth poses')."""
    from data_tools.formats.clouds import cloud_chunks, cloud_size, is_cloud_file

    xyz, _ = block_scene(500)
    value = _numpy_variants(xyz)[name]
    path = tmp_path / name
    if isinstance(value, dict):
        np.savez(path, **value)
    else:
        np.save(path, value)
    assert is_cloud_file(path) and cloud_size(path) == len(xyz)
    np.testing.assert_array_equal(np.concatenate(list(cloud_chunks(path, chunk=200))), xyz)


@pytest.mark.parametrize(
    ("name", "value", "needle"),
    [
        ("rows.npy", np.zeros((3, 50)), "looks like x, y, z rows"),
        ("col.npy", np.zeros((50, 1)), "expected (N, 3)"),
        ("text.npy", np.array(["a", "b"]), "numeric"),
        ("fields.npy", np.zeros(5, [("a", "f4"), ("b", "f4")]), "x, y, z fields"),
        ("two.npz", {"a": np.zeros((5, 3)), "b": np.zeros((5, 3))}, "which array holds the points"),
    ],
)
def test_numpy_arrays_that_are_not_clouds_are_one_line_errors(tmp_path, name, value, needle):
    from data_tools.errors import DataError
    from data_tools.formats.clouds import cloud_chunks

    path = tmp_path / name
    np.savez(path, **value) if isinstance(value, dict) else np.save(path, value)
    with pytest.raises(DataError) as err:
        list(cloud_chunks(path))
    assert needle in str(err.value) and str(err.value).count(str(path)) == 1 and "\n" not in str(err.value)


def test_an_ouster_npz_is_still_a_sweep_and_not_a_cloud(ouster_files):
    from data_tools.formats.clouds import is_cloud_file

    assert not is_cloud_file(ouster_files[0])


# ------------------------------------------------------------------ pose files for mapclass on a sequence


def _yaw_poses(n: int) -> np.ndarray:
    """A drive along x turning 2 deg per frame."""
    p = np.tile(np.eye(4), (n, 1, 1))
    a = np.radians(2.0) * np.arange(n)
    p[:, 0, 0], p[:, 0, 1], p[:, 1, 0], p[:, 1, 1] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a)
    p[:, 0, 3] = 0.8 * np.arange(n)
    return p


def test_tum_poses_are_matched_to_the_frames_by_time(tmp_path, caplog):
    """Before: ``mapclass SEQ --poses traj.tum`` (as ``odometry --pose-format tum`` writes it) was
    refused ('8 values, expected 12'). Now TUM poses are taken by time (a trajectory of more frames,
    out of order), or in order with a warning when the times are on another clock."""
    import logging

    from data_tools.formats.trajectory_io import read_pose_file, write_kitti_poses, write_tum_poses

    truth = _yaw_poses(8)
    times = 0.1 * np.arange(8) + 0.003
    write_kitti_poses(tmp_path / "p.kitti", truth)
    write_tum_poses(tmp_path / "p.tum", times, truth)
    np.testing.assert_allclose(read_pose_file(tmp_path / "p.kitti", times), truth, atol=1e-9)
    np.testing.assert_allclose(read_pose_file(tmp_path / "p.tum", times), truth, atol=1e-8)
    # poses for 3 of the frames, shuffled, beside poses of other times: the frames get their own
    rows = (tmp_path / "p.tum").read_text().splitlines()
    (tmp_path / "some.tum").write_text("# t x y z qx qy qz qw\n" + "\n".join([rows[5], rows[2], rows[7]]) + "\n")
    np.testing.assert_allclose(read_pose_file(tmp_path / "some.tum", times[[2, 5, 7]]), truth[[2, 5, 7]], atol=1e-8)
    write_tum_poses(tmp_path / "clock.tum", times + 1000.0, truth)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        np.testing.assert_allclose(read_pose_file(tmp_path / "clock.tum", times), truth, atol=1e-8)
    assert "clock.tum: the TUM times" in caplog.text and "file order" in caplog.text


def test_pose_files_that_cannot_place_the_frames_are_one_line_errors(tmp_path, caplog):
    import logging

    from data_tools.errors import DataError
    from data_tools.formats.trajectory_io import read_pose_file, write_kitti_poses, write_tum_poses

    truth = _yaw_poses(6)
    times = 0.1 * np.arange(6)
    write_tum_poses(tmp_path / "few.tum", times[:3] + 50.0, truth[:3])  # 3 poses, another clock
    scaled = truth.copy()
    scaled[3, :3, :3] *= 1.5  # a similarity, not a rotation
    write_kitti_poses(tmp_path / "scaled.kitti", scaled)
    mirrored = truth.copy()
    mirrored[1, :3, 2] *= -1
    write_kitti_poses(tmp_path / "mirrored.kitti", mirrored)
    (tmp_path / "seven.txt").write_text("1 2 3 4 5 6 7\n")
    for name, needle in [
        ("few.tum", "3 TUM poses for 6 frames"),
        ("scaled.kitti", "pose 4 (data row): its 3x3 block is not a rotation"),
        ("mirrored.kitti", "pose 2 (data row): its 3x3 block is not a rotation"),
        ("seven.txt", "7 values per line"),
    ]:
        with pytest.raises(DataError) as err:
            read_pose_file(tmp_path / name, times)
        assert needle in str(err.value) and name in str(err.value), str(err.value)
    # quaternions of norm 2 (not unit) are normalised, with a warning
    rows = np.loadtxt(tmp_path / "few.tum")
    rows[:, 4:] *= 2
    np.savetxt(tmp_path / "q2.tum", rows)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        got = read_pose_file(tmp_path / "q2.tum")
    np.testing.assert_allclose(got, truth[:3], atol=1e-8)
    assert "3 quaternions are not unit" in caplog.text


def test_mapclass_takes_tum_poses_like_kitti_poses_and_warns_of_extra_poses(tmp_path, caplog):
    import logging

    from data_tools.formats.kitti import KittiSequence
    from data_tools.formats.trajectory_io import write_kitti_poses, write_tum_poses
    from prc_slam.jobs.mapclass import map_from_dataset
    from tests.test_readers import make_kitti

    root = make_kitti(tmp_path / "seq", frames=4, labels=False)
    seq = KittiSequence(root)
    poses = _yaw_poses(4)
    write_kitti_poses(tmp_path / "p.kitti", poses)
    write_tum_poses(tmp_path / "p.tum", np.asarray(seq.times), poses)
    write_kitti_poses(tmp_path / "more.kitti", _yaw_poses(9))
    a = map_from_dataset(seq, 4, 1, tmp_path / "p.kitti")
    b = map_from_dataset(seq, 4, 1, tmp_path / "p.tum")
    np.testing.assert_allclose(a.points, b.points, atol=1e-6)
    with caplog.at_level(logging.WARNING, logger="prc_slam.mapclass"):
        c = map_from_dataset(seq, 4, 1, tmp_path / "more.kitti")
    np.testing.assert_allclose(a.points, c.points, atol=1e-6)
    assert "more.kitti: 9 poses for 4 frames: the first 4 are used" in caplog.text


# ------------------------------------------------------------------ degenerate map clouds


@pytest.mark.parametrize(
    ("name", "xyz", "needle"),
    [
        ("nan.npy", np.full((50, 3), np.nan), "no point has finite coordinates"),
        ("same.npy", np.tile([3.0, 4.0, 1.0], (80, 1)), "all 80 points lie at one position (3, 4, 1)"),
        ("same.las", np.tile([3.0, 4.0, 1.0], (80, 1)), "all 80 points lie at one position (3, 4, 1)"),
        ("one.las", np.array([[3.0, 4.0, 1.0]]), "a single point (3, 4, 1)"),
    ],
)
def test_a_cloud_without_spread_is_a_one_line_error(tmp_path, name, xyz, needle):
    """Before: 80 copies of one point came out as 80 'ground' points, and a cloud of NaNs 'wrote'
    a map_classified.las that was never written (LAS cannot store a point without coordinates)."""
    from data_tools.errors import DataError
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    path = tmp_path / name
    write_las(path, xyz) if name.endswith(".las") else np.save(path, xyz)
    with pytest.raises(DataError) as err:
        mapclass_job(path, Config(), tmp_path / "out")
    assert needle in str(err.value) and name in str(err.value)


def test_points_without_coordinates_are_counted_as_not_written(tmp_path):
    """An organised cloud's NaN slots get no_return and cannot be stored in LAS: the metrics (and
    the CLI) say how many points the LAS files lack."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, _ = block_scene(1500)
    holes = np.arange(len(xyz)) % 4 == 0
    xyz[holes] = np.nan
    np.save(tmp_path / "holes.npy", xyz)
    metrics = mapclass_job(tmp_path / "holes.npy", Config(), tmp_path / "out")
    assert metrics["points"] == len(xyz) and metrics["counts"]["no_return"] == int(holes.sum())
    assert metrics["points_not_written"] == int(holes.sum())
    out = laspy.read(metrics["files"]["all"])
    assert len(out) == int((~holes).sum())
    np.testing.assert_allclose(np.column_stack([out.x, out.y, out.z]), xyz[~holes], atol=5e-4)


# ------------------------------------------------------------------ PLY map clouds, LAS record counts


def _ply(path: Path, xyz: np.ndarray, fmt: str, *, extra: bool = True, faces: bool = True) -> Path:
    """A PLY of float32 x, y, z (with normals, an RGBA colour and two triangles when asked)."""
    order = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "<"}[fmt]
    props = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if extra:
        props += [("nx", "f4"), ("ny", "f4"), ("nz", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.zeros(len(xyz), [(k, order + t) for k, t in props])
    rec["x"], rec["y"], rec["z"] = xyz.T
    if extra:
        rec["nz"], rec["red"] = 1.0, 200
    names = {"f4": "float", "u1": "uchar"}
    head = f"ply\nformat {fmt} 1.0\ncomment h31\nelement vertex {len(xyz)}\n"
    head += "".join(f"property {names[t]} {k}\n" for k, t in props)
    head += "element face 2\nproperty list uchar int vertex_indices\n" if faces else ""
    head += "end_header\n"
    with path.open("wb") as f:
        f.write(head.encode())
        if fmt == "ascii":
            f.write("".join(" ".join(repr(v.item()) for v in r) + "\n" for r in rec).encode())
            f.write(b"3 0 1 2\n3 1 2 3\n" if faces else b"")
        else:
            f.write(rec.tobytes())
            if faces:
                tri = np.zeros(2, [("n", "u1"), ("i", order + "i4", (3,))])
                tri["n"], tri["i"] = 3, [[0, 1, 2], [1, 2, 3]]
                f.write(tri.tobytes())
    return path


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_map_clouds_are_read_exactly_and_cut_ones_are_errors(tmp_path, fmt):
    """Before (Open3D): a PLY cut in half was read as the whole vertex count, the missing half
    filled with zeros ('RPly: Error reading ...' on stderr, 10,000 points classified); a cut ascii
    PLY could end in a SystemError traceback; a PLY without y and z was read as points on a line."""
    from data_tools.errors import DataError
    from data_tools.formats.clouds import cloud_chunks

    xyz, _ = block_scene(400)
    xyz = xyz.astype(np.float32).astype(np.float64)
    path = _ply(tmp_path / "map.ply", xyz, fmt)
    np.testing.assert_array_equal(np.concatenate(list(cloud_chunks(path))), xyz)
    raw = path.read_bytes()
    (tmp_path / "cut.ply").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DataError, match="truncated"):
        list(cloud_chunks(tmp_path / "cut.ply"))
    (tmp_path / "x.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n" + bytes(40)
    )
    with pytest.raises(DataError, match="have no y, z"):
        list(cloud_chunks(tmp_path / "x.ply"))


def _patch_count(path: Path, count: int) -> Path:
    """Overwrite a LAS 1.4 header's point counts (legacy, at byte 107, and 64-bit, at 247)."""
    import struct

    raw = bytearray(path.read_bytes())
    struct.pack_into("<I", raw, 107, count)
    struct.pack_into("<Q", raw, 247, count)
    path.write_bytes(bytes(raw))
    return path


def test_las_records_beyond_the_header_count_are_an_error(tmp_path):
    """Before: a header announcing 1,000 of 3,000 records classified 1,000 points and dropped the
    rest without a word; a cut file said laspy's 'buffer size must be a multiple of element size'."""
    from data_tools.errors import DataError
    from data_tools.formats.clouds import cloud_chunks, cloud_classes, cloud_size
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = block_scene(2400)
    full = write_las(tmp_path / "full.las", xyz, classes)
    assert cloud_size(full) == len(xyz)  # a correct file passes the check
    short = tmp_path / "short.las"
    short.write_bytes(full.read_bytes())
    _patch_count(short, 1000)
    for call in (cloud_size, lambda p: list(cloud_chunks(p)), cloud_classes):
        with pytest.raises(DataError, match=f"header announces 1000 points, the file holds {len(xyz) - 1000} more"):
            call(short)
    cut = write_las(tmp_path / "cut.las", xyz, classes)
    cut.write_bytes(cut.read_bytes()[:-4500])
    with pytest.raises(DataError, match=r"header announces 3200 points, file holds \d+ \(truncated\?\)"):
        mapclass_job(cut, Config(), tmp_path / "out")


def test_a_second_run_into_the_same_folder_leaves_no_class_files_of_the_first(tmp_path):
    """Before: classifying a building tile and then a bare field into the same ``--out`` left the
    first run's ``building.las`` (and its ``.las`` files beside a later ``--laz`` run's): the folder
    said the field had buildings. Files that are not ours stay."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = block_scene(3000)
    write_las(tmp_path / "tile.las", xyz, classes)
    rng = np.random.default_rng(5)
    field = np.column_stack([rng.uniform(0, 40, 4000), rng.uniform(0, 40, 4000), rng.normal(0, 0.02, 4000)])
    np.save(tmp_path / "field.npy", field)
    out = tmp_path / "out"
    first = mapclass_job(tmp_path / "tile.las", Config(), out)
    assert "building" in first["files"]
    (out / "notes.las").write_bytes(b"mine")
    second = mapclass_job(tmp_path / "field.npy", Config(), out, laz=True)
    assert "building" not in second["files"]
    assert sorted(f.name for f in out.iterdir() if f.is_file()) == sorted(
        [Path(p).name for p in second["files"].values()] + ["notes.las"]
    )


# ------------------------------------------------------------------ detect on what is not a sweep


def test_detect_warns_when_one_class_takes_every_return(caplog):
    """Before: a flat 80 m x 80 m aerial-like tile given to ``detect`` came out 120,000 of 120,000
    points 'vertical' without a word (PRC's one-class check does not look at the detectors'
    labels). Hand case on the sink: 1,200 returns, all one class, warned once and counted; a
    frame of two classes is not."""
    import logging
    from types import SimpleNamespace

    from prc_slam import labels as L
    from prc_slam.jobs.classify import OneClassWatch

    ranges = np.ones(1500)
    ranges[:300] = 0  # slots without a return do not count
    one = np.full(1500, L.VERTICAL, np.uint8)
    two = one.copy()
    two[300:800] = L.GROUND

    def step(labels):
        return SimpleNamespace(online=SimpleNamespace(labels=labels), scan=SimpleNamespace(ranges=ranges, source="t"))

    watch = OneClassWatch()
    with caplog.at_level(logging.WARNING, logger="prc_slam.jobs"):
        watch.frame(step(two))
        assert watch.frames == 0 and not caplog.records
        watch.frame(step(one))
        watch.frame(step(one))
    assert watch.frames == 2
    assert [r.getMessage() for r in caplog.records] == [
        "t: the online detectors put 100.0% of the returns in one class (vertical): is this a sweep of a spinning "
        "sensor (not a map or an aerial tile: use mapclass), in metres?"
    ]


def test_detect_on_real_sweeps_is_not_warned_of_one_class(caplog):
    import logging

    from data_tools.datasets import open_dataset
    from prc_slam.jobs.classify import detect_job

    path = Path(__file__).resolve().parents[2] / "shared" / "data" / "multisensor" / "velodyne_vlp16.pcd"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    with caplog.at_level(logging.WARNING, logger="prc_slam.jobs"):
        metrics, _ = detect_job(path)
    assert metrics["frames_one_class"] == 0 and "one class" not in caplog.text
    assert metrics["points"] == open_dataset(path)[0].n_points


def test_a_folder_of_las_tiles_given_to_mapclass_says_to_give_one_cloud(tmp_path):
    """Before: 'unknown input format (expected a simulated sequence with sim.json, ...)'."""
    from data_tools.errors import DataError
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = block_scene(300)
    (tmp_path / "tiles").mkdir()
    write_las(tmp_path / "tiles" / "a.las", xyz, classes)
    write_las(tmp_path / "tiles" / "b.las", xyz + 50, classes)
    with pytest.raises(DataError, match="a folder of 2 LAS/LAZ files: mapclass classifies one cloud file"):
        mapclass_job(tmp_path / "tiles", Config(), tmp_path / "out")


def test_an_unknown_file_given_to_mapclass_lists_the_cloud_formats(tmp_path):
    """Before: the message listed the sequence formats only (sim.json, velodyne/, pcap, bags), not
    the PLY / NPY / NPZ clouds mapclass reads."""
    from data_tools.errors import DataError
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    (tmp_path / "cloud.xyz").write_text("x y z\n1 2 3\n")
    with pytest.raises(
        DataError, match=r"cloud.xyz: unknown cloud format '.xyz': mapclass reads one cloud file \(.las"
    ):
        mapclass_job(tmp_path / "cloud.xyz", Config(), tmp_path / "out")


def test_reference_classes_without_a_map_class_are_warned_with_their_counts(tmp_path, caplog):
    """Before: ASPRS water (9), bridge deck (17) or a producer's own class 40 in a tile's
    classification were scored without a word (each such point a false positive of the class it
    is given); standard classes with a counterpart (2, 3-6, 11, 20) are not warned of."""
    import logging

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

    xyz, classes = block_scene(900)
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
    """Before: ``mapclass map.las --poses p.txt --every 3`` classified the cloud and ignored both."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    xyz, classes = block_scene(300)
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
