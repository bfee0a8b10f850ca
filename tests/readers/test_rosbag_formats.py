"""ROS recordings written with the rosbags library: compressed rosbag2 bags (sqlite3 and MCAP, per
message and per file) read from the folder or any of their files, PointCloud2 layouts, ROS 1 bags
with compressed chunks and two publishers, topics with messages of two types, empty and cut bags.
"""

from __future__ import annotations

import gc
import logging
import shutil
import sys

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.formats.rosbag import RosbagSequence, cloud_from_records
from tests.inputs.rosbags import COLS, EPOCH, ROWS, VELODYNE, room_sweep, ros2_sweeps, write_ros2
from tests.messages import one_line


def assert_sweep_read(scan, rec: np.ndarray) -> None:
    """Every point kept in input order, at its coordinates, in its beam's row (top beam first),
    with its time; NaN points as no returns."""
    assert scan.n_points == len(rec)
    want = np.column_stack([rec["x"], rec["y"], rec["z"]]).astype(np.float64)
    ok = np.isfinite(want).all(axis=1)
    np.testing.assert_allclose(scan.points().astype(np.float64)[ok], want[ok], atol=1e-6)
    rows = scan.point_slot[ok] // scan.shape[1]
    np.testing.assert_array_equal(rows, ROWS - 1 - rec["ring"][ok].astype(np.int64))
    times = scan.point_times()[ok] - scan.meta["frame_time"]
    np.testing.assert_allclose(times, rec["time"][ok].astype(np.float64), atol=1e-5)
    assert scan.shape == (ROWS, COLS)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("compression", ["MESSAGE", "FILE"])
def test_compressed_rosbag2_bags_are_read_from_the_folder_or_any_of_their_files(tmp_path, storage, compression):
    """Compressed rosbag2 bags (sqlite3 and MCAP storage, per-message and per-file compression) are read from
    their folder or from any of their storage files, through the folder's ``metadata.yaml``, in the bag's own
    storage."""
    msgs, recs = ros2_sweeps()
    bag = write_ros2(tmp_path / "bag", msgs, storage=storage, compression=compression)
    (inner,) = [p for p in bag.iterdir() if p.name != "metadata.yaml"]
    for given in (bag, bag / "metadata.yaml", inner):
        ds = open_dataset(given)
        assert len(ds) == 2 and ds.storage == storage, given
        for scan, rec in zip(ds, recs, strict=True):
            assert_sweep_read(scan, rec)
        ds.close()


def test_a_compressed_rosbag2_file_without_its_metadata_is_a_one_line_error(tmp_path, monkeypatch):
    """A message-compressed ``.db3`` or a ``.mcap.zstd`` without its ``metadata.yaml`` is a one-line error
    saying why; an error while opening (two ``.db3`` without metadata) prints nothing from
    ``RosbagSequence.__del__``."""
    msgs, _ = ros2_sweeps(frames=1)
    alone = tmp_path / "alone"
    alone.mkdir()
    for compression, storage in (("MESSAGE", "sqlite3"), ("FILE", "mcap")):
        bag = write_ros2(tmp_path / compression, msgs, storage=storage, compression=compression)
        for p in bag.iterdir():
            if p.name != "metadata.yaml":
                shutil.copy(p, alone / p.name)
    with pytest.raises(DataError) as exc:
        open_dataset(alone / "MESSAGE.db3")
    assert "zstd-compressed" in one_line(exc, alone / "MESSAGE.db3")
    with pytest.raises(DataError) as exc:
        open_dataset(alone / "FILE.mcap.zstd")
    assert "compressed whole" in one_line(exc, alone / "FILE.mcap.zstd")
    two = tmp_path / "two"
    two.mkdir()
    plain = write_ros2(tmp_path / "plain", msgs)
    for name in ("a.db3", "b.db3"):
        shutil.copy(plain / "plain.db3", two / name)
    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    with pytest.raises(DataError, match=r"2 \.db3 files without a metadata\.yaml"):
        RosbagSequence(two)
    gc.collect()
    assert not unraisable, [u.exc_value for u in unraisable]


def layout(big: bool = False, xyz: str = "f4", ring: str = "u2", time: str = "f4", pad: int = 0) -> np.dtype:
    o = ">" if big else "<"
    formats = [o + xyz] * 3 + [o + "f4", o + ring, o + time]
    offsets, k = [], 0
    for i, f in enumerate(formats):
        offsets.append(k)
        k += np.dtype(f).itemsize + (pad if i == 2 else 0)
    return np.dtype({"names": list(VELODYNE.names), "formats": formats, "offsets": offsets, "itemsize": k + pad})


@pytest.mark.parametrize(
    "dtype, options",
    [
        (layout(big=True), {}),
        (layout(pad=4), {"row_pad": 16}),
        (layout(xyz="f8", ring="u1", time="f8"), {}),
        (VELODYNE, {"nan": 0.1}),
        (layout(big=True), {"organised": True, "nan": 0.1, "row_pad": 8}),
    ],
    ids=["big-endian", "padded", "float64-uint8-ring", "not-dense", "organised-big-endian-row-padded"],
)
def test_pointcloud2_layouts_in_a_bag_give_the_points_rows_and_times(tmp_path, dtype, options):
    """Big-endian, padded, row-padded, float64 and organised PointCloud2 layouts with NaN: every layout is
    decoded exactly and organised by its ring field."""
    msgs, recs = ros2_sweeps(dtype, **options)
    bag = write_ros2(tmp_path / "bag", msgs, storage="mcap")
    for scan, rec in zip(open_dataset(bag), recs, strict=True):
        assert_sweep_read(scan, rec)
        assert scan.meta["organize"]["rings"] == ROWS


def ros1_messages(frames: int = 3) -> tuple[object, list, list[np.ndarray]]:
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    recs = [room_sweep(VELODYNE, i) for i in range(frames)]
    msgs = []
    for i, rec in enumerate(recs):
        c = cloud_from_records(rec, stamp_ns=EPOCH * 10**9 + i * 10**8)
        header = T["std_msgs/msg/Header"](
            seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=c.stamp_sec, nanosec=c.stamp_nanosec), frame_id="v"
        )
        fields = [
            T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
            for f in c.fields
        ]
        msgs.append(
            T["sensor_msgs/msg/PointCloud2"](
                header=header,
                height=1,
                width=c.width,
                fields=fields,
                is_bigendian=False,
                point_step=c.point_step,
                row_step=c.width * c.point_step,
                data=c.raw.reshape(-1),
                is_dense=True,
            )
        )
    return ts, msgs, recs


@pytest.mark.parametrize("compression", [None, "BZ2", "LZ4"])
def test_ros1_bags_with_compressed_chunks_and_two_publishers(tmp_path, compression):
    """ROS 1 bags with bz2 / lz4 chunks and two connections (publishers) on one topic are read in order and by
    index."""
    from rosbags.rosbag1 import Writer

    ts, msgs, recs = ros1_messages()
    path = tmp_path / "two.bag"
    w = Writer(path)
    if compression:
        w.set_compression(Writer.CompressionFormat[compression])
    w.open()
    conns = [
        w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts, callerid=f"/n{k}") for k in (0, 1)
    ]
    for i, m in enumerate(msgs):
        w.write(conns[i % 2], EPOCH * 10**9 + i * 10**8, ts.serialize_ros1(m, "sensor_msgs/msg/PointCloud2"))
    w.close()
    ds = open_dataset(path)
    assert len(ds) == 3
    for scan, rec in zip(ds, recs, strict=True):
        assert_sweep_read(scan, rec)
    assert [ds[i].meta["ros"].seq for i in (2, 0, 1)] == [2, 0, 1]


def test_a_topic_with_messages_of_another_type_reads_its_clouds(tmp_path, caplog):
    """A topic whose publishers sent PointCloud2 and another type (rosbags gives it no type) reads its
    PointCloud2 messages, with a warning."""
    from rosbags.rosbag1 import Writer

    ts, msgs, recs = ros1_messages(2)
    path = tmp_path / "mixed.bag"
    w = Writer(path)
    w.open()
    cloud = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts, callerid="/a")
    text = w.add_connection("/points", "std_msgs/msg/String", typestore=ts, callerid="/b")
    for i, m in enumerate(msgs):
        t = EPOCH * 10**9 + i * 10**8
        w.write(cloud, t, ts.serialize_ros1(m, "sensor_msgs/msg/PointCloud2"))
        w.write(text, t + 1000, ts.serialize_ros1(ts.types["std_msgs/msg/String"](data="x"), "std_msgs/msg/String"))
    w.close()
    with caplog.at_level(logging.WARNING, logger="prc_slam.rosbag"):
        ds = open_dataset(path)
    assert any("also carries std_msgs/msg/String" in r.message for r in caplog.records)
    assert len(ds) == 2
    for scan, rec in zip(ds, recs, strict=True):
        assert_sweep_read(scan, rec)


def test_empty_and_cut_ros1_bags_are_one_line_errors(tmp_path):
    """Empty and cut ROS 1 bags are one-line errors naming the file."""
    from rosbags.rosbag1 import Writer

    ts, msgs, _ = ros1_messages(3)
    empty = tmp_path / "empty.bag"
    w = Writer(empty)
    w.open()
    w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
    w.close()
    with pytest.raises(DataError, match="holds no messages") as exc:
        open_dataset(empty)
    one_line(exc, empty)
    full = tmp_path / "full.bag"
    w = Writer(full)
    w.set_compression(Writer.CompressionFormat.LZ4)
    w.open()
    conn = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
    for i, m in enumerate(msgs):
        w.write(conn, EPOCH * 10**9 + i * 10**8, ts.serialize_ros1(m, "sensor_msgs/msg/PointCloud2"))
    w.close()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.raises(DataError, match="damaged or truncated") as exc:
        open_dataset(cut)
    one_line(exc, cut)
