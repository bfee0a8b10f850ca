"""Recording formats and sensor modes the project did not read at first: each test generates a small input
in ``tmp_path`` with the format's own library (rosbags, ouster-sdk) or from the format's bytes
(Velodyne, Hesai packets) and checks that the readers give the right points or a clear one-line
error.

Found and fixed:

- Ouster metadata of another lidar mode than the capture's: a 2048-column capture read with a
  1024-column json lost half of every sweep without a word; a 512-column capture read with a
  1024-column json put every point at twice its azimuth, warned only as "512 of 1024 columns
  missing (dropped packets ...)". Both are now an error naming the measurement ids and the mode.
- A dual-return Ouster profile read its first return only, silently: now warned.
- A Hesai capture (``0xEEFF`` packets) said "no Ouster sensor metadata"; now it says what it is
  and how to convert it. An unknown capture without json lists its UDP traffic.
- A rosbag2 storage file given alone (``.db3`` / ``.mcap`` of a message-compressed bag,
  ``.db3.zstd`` / ``.mcap.zstd`` of a file-compressed one) was "damaged or truncated ... Invalid
  or unsupported CDR encapsulation" or an "unknown input format": it is now read through its
  folder's ``metadata.yaml``, and without one the error says why. A file-compressed MCAP bag was
  taken for sqlite3 storage (the filtered bag came out in the other storage).
- An error while opening a recording (e.g. two ``.db3`` without ``metadata.yaml``) also printed
  an "Exception ignored in ``RosbagSequence.__del__``" traceback.
- A ROS topic with connections of two message types (rosbags gives it no type) crashed with
  ``AttributeError: 'NoneType' object has no attribute 'replace'``; its PointCloud2 messages are
  now read, with a warning.
- ``--model`` naming another Velodyne than the packets' factory byte gave the decoder's
  "Expected model ID <34> in packet, got <40> ... set the model in Config explicitly".

Found fine (kept as checks): zstd-compressed rosbag2 bags (sqlite3 and MCAP, per message and per
file), big-endian, padded, row-padded, float64 and organised PointCloud2 with NaN; ROS 1 bz2 / lz4
chunks, two publishers on one topic, empty and cut bags; VLP-32C, HDL-32E and VLS-128 captures
(single and dual return), VLP-16 at 300 and 1200 rpm; Ouster 512x10, 1024x20, 2048x10 and the
legacy, low-data-rate and dual-return profiles.
"""

from __future__ import annotations

import gc
import json
import logging
import shutil
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.formats.rosbag import RosbagSequence, cloud_from_records

from .conftest import SHARED_DATA
from .test_pcap import vlp16_stream, write_pcap

EPOCH = 1_700_000_000  # s
ROWS, COLS = 16, 900


def one_line(exc: pytest.ExceptionInfo, path: Path) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg, msg
    return msg


# --------------------------------------------------------------------------------------------
# ROS bags

VELODYNE = np.dtype(  # velodyne_pointcloud PointXYZIRT, packed
    {
        "names": ["x", "y", "z", "intensity", "ring", "time"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
        "offsets": [0, 4, 8, 12, 16, 18],
        "itemsize": 22,
    }
)


def room_sweep(dtype: np.dtype, seed: int = 0, *, organised: bool = False, nan: float = 0.0) -> np.ndarray:
    """A 16-beam sweep of a round room: records (rows, cols) ring by ring (``organised``: row 0 =
    ring 0, the lowest beam) or (cols * rows,) firing by firing; ``time`` in s from the stamp."""
    rng = np.random.default_rng(seed)
    el = np.radians(np.linspace(-15.0, 15.0, ROWS))[:, None]
    az = np.radians(np.arange(COLS) * 360.0 / COLS)[None, :]
    r = (15.0 + 5.0 * np.sin(3 * az)) / np.cos(el)
    r = np.minimum(r, np.where(el < 0, 1.8 / np.maximum(-np.sin(el), 1e-9), np.inf)) + rng.normal(0, 0.01, r.shape)
    rec = np.zeros((ROWS, COLS), dtype)
    rec["x"], rec["y"], rec["z"] = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)
    rec["ring"] = np.arange(ROWS)[:, None]
    rec["time"] = np.arange(COLS)[None, :] * 0.1 / COLS
    rec["intensity"] = 50
    if nan:
        gone = rng.random(rec.shape) < nan
        for c in "xyz":
            rec[c][gone] = np.nan
    return rec if organised else rec.T.reshape(-1)


def ros2_message(typestore, rec: np.ndarray, stamp_ns: int, *, height: int = 1, row_pad: int = 0):
    """A ``sensor_msgs/msg/PointCloud2`` of ``rec`` (its dtype's layout), ``row_pad`` bytes after each row."""
    c = cloud_from_records(rec.reshape(-1), height=height, stamp_ns=stamp_ns, is_dense=None)
    T = typestore.types
    data = c.raw.reshape(c.height, c.width * c.point_step)
    data = np.concatenate([data, np.full((c.height, row_pad), 0xAB, np.uint8)], axis=1)
    return T["sensor_msgs/msg/PointCloud2"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=c.stamp_sec, nanosec=c.stamp_nanosec), frame_id="lidar"
        ),
        height=c.height,
        width=c.width,
        fields=[
            T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
            for f in c.fields
        ],
        is_bigendian=c.is_bigendian,
        point_step=c.point_step,
        row_step=c.width * c.point_step + row_pad,
        data=data.reshape(-1),
        is_dense=c.is_dense,
    )


def write_ros2(path: Path, msgs: list, *, storage: str = "sqlite3", compression: str | None = None) -> Path:
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3)
    if compression:
        w.set_compression(CompressionMode[compression], CompressionFormat.ZSTD)
    w.open()
    conn = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
    for m in msgs:
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        w.write(conn, stamp, ts.serialize_cdr(m, "sensor_msgs/msg/PointCloud2"))
    w.close()
    return path


def ros2_sweeps(dtype: np.dtype = VELODYNE, frames: int = 2, **options) -> tuple[list, list[np.ndarray]]:
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    organised = options.pop("organised", False)
    nan = options.pop("nan", 0.0)
    recs = [room_sweep(dtype, i, organised=organised, nan=nan) for i in range(frames)]
    height = ROWS if organised else 1
    msgs = [ros2_message(ts, r, EPOCH * 10**9 + i * 10**8, height=height, **options) for i, r in enumerate(recs)]
    return msgs, [r.reshape(-1) for r in recs]


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
    """Before: the folder was read, but its storage file given alone was 'damaged or truncated
    recording ... Invalid or unsupported CDR encapsulation' (message compression) or an 'unknown
    input format' (file compression, ``.db3.zstd`` / ``.mcap.zstd``); a file-compressed MCAP bag
    was taken for sqlite3 storage."""
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
    """Before: 'damaged or truncated recording ... Invalid or unsupported CDR encapsulation' for a
    message-compressed ``.db3`` alone, 'unknown input format' for a ``.mcap.zstd`` alone; and an
    error raised while opening (two ``.db3`` without metadata.yaml) also printed 'Exception ignored
    in RosbagSequence.__del__ ... AttributeError'."""
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
    """Fine before: every layout is decoded exactly and organised by its ring field."""
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
    """Fine before: bz2 / lz4 chunks, two connections (publishers) on one topic, read in order
    and by index."""
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
    """Before: a topic whose publishers sent PointCloud2 and another type (rosbags gives it no
    type) crashed with ``AttributeError: 'NoneType' object has no attribute 'replace'``."""
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
    """Fine before."""
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


# --------------------------------------------------------------------------------------------
# Velodyne captures

FIRING_32 = 55.296e-6  # s per firing of the 32-laser models (one block)


def velodyne32_stream(factory: int, *, dual: bool = False, n_sweeps: float = 1.3, unit: float = 0.004):
    """Data packets of a 32-laser Velodyne (one firing per block; ``dual``: blocks in pairs, last
    return then strongest, the last 2 m behind on every third laser) in a round room."""
    deg_per_s = 3600.0
    firings = int(n_sweeps * 0.1 / FIRING_32) // 12 * 12
    per_packet = 6 if dual else 12
    payloads, stamps = [], []
    for p0 in range(0, firings, per_packet):
        buf = bytearray()
        for j in range(p0, p0 + per_packet):
            az = (j * FIRING_32 * deg_per_s + 10.0) % 360.0
            r = 10.0 + 2.0 * np.sin(np.radians(az) * 3)
            for last in (True, False) if dual else (False,):
                buf += b"\xff\xee" + struct.pack("<H", round(az * 100) % 36000)
                for k in range(32):
                    rk = r + 2.0 if last and k % 3 == 0 else r
                    buf += struct.pack("<HB", int(rk / unit), 50 if last else 100)
        buf += struct.pack("<IBB", int(p0 * FIRING_32 * 1e6), 0x39 if dual else 0x37, factory)
        payloads.append(bytes(buf))
        stamps.append(1.0e9 + p0 * FIRING_32)
    return payloads, stamps


def vls128_stream(n_sweeps: float = 1.2):
    """VLS-128 data packets: 3 firing groups of 4 blocks (flags 0xFFEE, 0xFFDD, 0xFFCC, 0xFFBB for
    lasers 0-31, 32-63, 64-95, 96-127), all at 10 m."""
    group_dt = 53.3e-6
    groups = int(n_sweeps * 0.1 / group_dt) // 3 * 3
    flags = [b"\xff\xee", b"\xff\xdd", b"\xff\xcc", b"\xff\xbb"]
    payloads, stamps = [], []
    for g0 in range(0, groups, 3):
        buf = bytearray()
        for g in range(g0, g0 + 3):
            az = (g * group_dt * 3600.0 + 10.0) % 360.0
            for flag in flags:
                buf += flag + struct.pack("<H", round(az * 100) % 36000) + struct.pack("<HB", 2500, 80) * 32
        buf += struct.pack("<IBB", int(g0 * group_dt * 1e6), 0x37, 0xA1)
        payloads.append(bytes(buf))
        stamps.append(1.0e9 + g0 * group_dt)
    return payloads, stamps


@pytest.mark.parametrize(
    "model, options, rows",
    [
        ("VLP32C", {"factory": 0x28}, 32),
        ("HDL32E", {"factory": 0x21, "unit": 0.002}, 32),
        ("VLP32C", {"factory": 0x28, "dual": True}, 32),
        ("VLS128", {}, 128),
    ],
    ids=["vlp32c", "hdl32e", "vlp32c-dual", "vls128"],
)
def test_other_velodyne_models_give_one_row_per_laser(tmp_path, model, options, rows):
    """Fine before: the model from the factory byte, every laser a row, every decoded point kept
    (a dual return's last return shares its firing's slot), one sweep per revolution."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    stream = velodyne32_stream(**options) if options else vls128_stream()
    path = write_pcap(tmp_path / f"{model}.pcap", *stream)
    ds = open_dataset(path)
    assert ds.model == model
    pts = ds.sweep(0)[1]
    scan = ds[0]
    report = scan.meta["organize"]
    assert scan.shape[0] == rows and report["rings"] == rows and not report["warnings"]
    assert scan.n_points == len(pts) and np.unique(pts["ring"]).size == rows
    assert 0.095 < np.ptp(scan.point_times()) < 0.105
    r = np.linalg.norm(scan.points().astype(np.float64), axis=1)
    assert 7.9 < r.min() and r.max() < 14.1
    last = int((pts["return_type"] == 2).sum())  # velodyne_decoder ReturnMode.LAST
    assert scan.meta.get("second_returns", 0) == last and (last > 0.25 * len(pts)) == ("dual" in options)


@pytest.mark.parametrize("rpm, cols", [(300, 3600), (1200, 900)])
def test_vlp16_at_other_speeds_gives_one_column_per_firing(tmp_path, rpm, cols):
    """Fine before: sweeps of 60 / rpm seconds with one column per firing."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.2, rpm=rpm)
    ds = open_dataset(write_pcap(tmp_path / "v.pcap", payloads, stamps))
    scan = ds[1]
    assert scan.shape == (16, cols)
    np.testing.assert_allclose(np.diff(ds.times)[0], 60.0 / rpm, rtol=0.01)
    assert np.ptp(scan.point_times()) == pytest.approx(60.0 / rpm, rel=0.05)


def test_a_velodyne_model_other_than_the_packets_is_a_one_line_error(tmp_path):
    """Before: the decoder's 'Expected model ID <34> in packet, got <40>. Note: if the device is
    HDL-64E, please set the model in Config explicitly.'; models sharing packets still read."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    path = write_pcap(tmp_path / "v32.pcap", *velodyne32_stream(0x28))
    with pytest.raises(DataError) as exc:
        open_dataset(path, model="VLP16")
    assert "--model VLP16" in one_line(exc, path) and "VLP32C (factory byte 0x28)" in str(exc.value)
    payloads, stamps, _ = vlp16_stream(n_sweeps=1.2)
    assert open_dataset(write_pcap(tmp_path / "v16.pcap", payloads, stamps), model="PuckLite").model == "PuckLite"


# --------------------------------------------------------------------------------------------
# Ouster captures written by ouster-sdk

OUSTER_JSON = SHARED_DATA / "ouster" / "pcaps" / "OS-1-128_v2.3.0_1024x10.json"


def ouster_capture(root: Path, name: str, mode: str, profile: str, frames: int = 2) -> tuple[Path, list]:
    """A capture of ``frames`` sweeps (ranges in mm, measurement order) in ``mode`` / ``profile``
    from the OS-1-128's metadata, written with ouster-sdk; its json beside it."""
    core = pytest.importorskip("ouster.sdk.core")
    from ouster.sdk import pcap

    if not OUSTER_JSON.is_file():
        pytest.skip(f"Ouster metadata not found: {OUSTER_JSON}")
    meta = json.loads(OUSTER_JSON.read_text())
    cols, hz = (int(v) for v in mode.split("x"))
    fmt = meta["data_format"]
    meta["lidar_mode"] = mode
    fmt.update(columns_per_frame=cols, column_window=[0, cols - 1], udp_profile_lidar=profile)
    fmt["pixel_shift_by_row"] = [s * cols // 1024 for s in fmt["pixel_shift_by_row"]]
    (root / f"{name}.json").write_text(json.dumps(meta))
    info = core.SensorInfo(json.dumps(meta))
    packet_format = core.PacketFormat(info)
    rng = np.random.default_rng(0)
    packets, truth = [], []
    for f in range(frames):
        frame = core.LidarFrame(info)
        r = 5000 + 1000 * np.sin(np.linspace(0, 6 * np.pi, cols))[None, :] + 10 * np.arange(128)[:, None]
        r = r.astype(np.uint32)
        r[rng.random(r.shape) < 0.05] = 0
        frame.field("RANGE")[:] = r
        if frame.has_field("RANGE2"):
            frame.field("RANGE2")[:] = np.where(r > 0, r + 2000, 0)
        frame.frame_id = 100 + f
        frame.timestamp[:] = 10**18 + f * 10**9 // hz + np.arange(cols, dtype=np.uint64) * (10**9 // hz // cols)
        frame.status[:] = 1
        frame.measurement_id[:] = np.arange(cols)
        packets += list(core.frame_to_packets(frame, packet_format, info.init_id, int(info.sn)))
        truth.append(r)
    path = root / f"{name}.pcap"
    pcap.record(packets, str(path), lidar_port=7502)
    return path, truth


@pytest.mark.parametrize(
    "mode, profile, resolution_mm",
    [
        ("512x10", "RNG19_RFL8_SIG16_NIR16", 0),
        ("2048x10", "RNG19_RFL8_SIG16_NIR16", 0),
        ("1024x20", "LEGACY", 0),
        ("1024x10", "RNG15_RFL8_NIR8", 8),
        ("1024x10", "RNG19_RFL8_SIG16_NIR16_DUAL", 0),
    ],
)
def test_ouster_lidar_modes_and_profiles_read_every_pixel(tmp_path, caplog, mode, profile, resolution_mm):
    """Fine before, except that the second return of a dual-return profile was dropped without a
    word (now warned)."""
    path, truth = ouster_capture(tmp_path, "cap", mode, profile)
    cols, hz = (int(v) for v in mode.split("x"))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        ds = open_dataset(path, destaggered=False)  # measurement order, as the packets were written
        scans = list(ds)
    assert len(scans) == 2
    np.testing.assert_allclose(np.diff(ds.times), 1.0 / hz, rtol=1e-3)
    for scan, r in zip(scans, truth, strict=True):
        assert scan.shape == (128, cols)
        got = np.round(scan.ranges * 1000).astype(np.int64)
        assert ((got > 0) == (r > 0)).all()
        assert np.abs(got - r).max() <= resolution_mm
    dual = [rec.message for rec in caplog.records if "second returns (RANGE2) are not read" in rec.message]
    assert len(dual) == (1 if profile.endswith("DUAL") else 0)
    assert not [rec for rec in caplog.records if "columns missing" in rec.message]


@pytest.mark.parametrize("capture_mode, json_mode", [("2048x10", "1024x10"), ("512x10", "1024x10")])
def test_ouster_metadata_of_another_lidar_mode_is_a_one_line_error(tmp_path, capture_mode, json_mode):
    """Before: a 2048-column capture read with a 1024x10 json gave sweeps of 1024 columns, half the
    points lost without a word; a 512-column capture read with a 1024x10 json put every point at
    twice its azimuth, warned only as '512 of 1024 columns missing (dropped packets ...)'."""
    path, _ = ouster_capture(tmp_path, "cap", capture_mode, "RNG19_RFL8_SIG16_NIR16")
    ouster_capture(tmp_path, "other", json_mode, "RNG19_RFL8_SIG16_NIR16", frames=1)
    shutil.copy(tmp_path / "other.json", tmp_path / "cap.json")
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    text = one_line(exc, path)
    cols = int(capture_mode.split("x")[0])
    assert f"0..{cols - 1}" in text and f"lidar_mode {json_mode}" in text and "--meta" in text


def test_a_hesai_capture_says_what_it_is(tmp_path):
    """Before: 'no Ouster sensor metadata: expected hesai.json beside it' (and, with a json beside
    it, 'no lidar packets matching'). Ouster and Velodyne captures are not affected."""
    from data_tools.formats.ouster_pcap import OusterPcapSequence

    pandar40p = [b"\xee\xff" + bytes(1260)] * 40
    gps = [b"$GPRMC" + bytes(506)] * 10  # Hesai GPS packets between the data
    payloads = pandar40p[:20] + gps + pandar40p[20:]
    path = write_pcap(tmp_path / "hesai.pcap", payloads, [1e9 + k * 1e-4 for k in range(len(payloads))])
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    assert "Hesai lidar packets (1262 bytes" in one_line(exc, path) and "PointCloud2" in str(exc.value)
    (tmp_path / "hesai.json").write_text("{}")
    with pytest.raises(DataError, match="Hesai lidar packets") as exc:
        OusterPcapSequence(path)
    other = write_pcap(tmp_path / "robosense.pcap", [bytes(1248)] * 20, [1e9 + k * 1e-4 for k in range(20)], port=6699)
    with pytest.raises(DataError) as exc:
        open_dataset(other)
    assert "port 6699: 20 of 1248 bytes" in one_line(exc, other)


def test_classify_on_new_inputs_runs_or_says_why(tmp_path):
    """``prc-slam classify`` on a file-compressed MCAP bag and a VLP-32C capture counts every
    point; on an Ouster capture with another mode's json and on a Hesai capture it is one
    ``error:`` line (exit 2)."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    from typer.testing import CliRunner

    from prc_slam.cli import app

    msgs, recs = ros2_sweeps()
    bag = write_ros2(tmp_path / "bag", msgs, storage="mcap", compression="FILE")
    vlp32 = write_pcap(tmp_path / "vlp32c.pcap", *velodyne32_stream(0x28, n_sweeps=2.2))
    runner = CliRunner()
    for given, points in ((bag, sum(len(r) for r in recs)), (vlp32, None)):
        out = tmp_path / f"{given.stem}.json"
        res = runner.invoke(app, ["classify", str(given), "--json", str(out)])
        assert res.exit_code == 0, res.output
        metrics = json.loads(out.read_text())
        assert metrics["frames"] == (2 if points else 3)
        if points:
            assert metrics["points"] == points
    hesai = write_pcap(tmp_path / "hesai.pcap", [b"\xee\xff" + bytes(1078)] * 20, [1e9 + k * 1e-4 for k in range(20)])
    res = runner.invoke(app, ["classify", str(hesai)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Hesai" in errors[0], res.output
