"""ROS recordings built with rosbags: VLP-16 packet topics (ROS 1 and 2) and PointCloud2 sweeps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data_tools.formats.rosbag import cloud_from_records


def velodyne_scan_bag(path: Path, kind: str, payloads: list[bytes], stamps: list[float], topic: str) -> Path:
    """A recording of raw packets as ``rosbag record /velodyne_packets`` stores them: one
    ``velodyne_msgs/VelodyneScan`` per 75 packets, each packet with its stamp."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = get_types_from_msg("builtin_interfaces/Time stamp\nuint8[1206] data\n", "velodyne_msgs/msg/VelodynePacket")
    header = "std_msgs/Header header\nVelodynePacket[] packets\n"
    types.update(get_types_from_msg(header, "velodyne_msgs/msg/VelodyneScan"))
    ts.register(types)
    T = ts.types

    def stamp(t: float):
        sec = int(t)
        return T["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9))

    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer, serialize = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3), ts.serialize_cdr
    with writer as w:
        conn = w.add_connection(topic, "velodyne_msgs/msg/VelodyneScan", typestore=ts)
        for k in range(0, len(payloads), 75):
            packets = [
                T["velodyne_msgs/msg/VelodynePacket"](stamp=stamp(t), data=np.frombuffer(p, np.uint8))
                for p, t in zip(payloads[k : k + 75], stamps[k : k + 75], strict=True)
            ]
            extra = {"seq": k} if kind == "ros1" else {}
            hdr = T["std_msgs/msg/Header"](stamp=stamp(stamps[k]), frame_id="velodyne", **extra)
            msg = T["velodyne_msgs/msg/VelodyneScan"](header=hdr, packets=packets)
            w.write(conn, round(stamps[k] * 1e9), serialize(msg, "velodyne_msgs/msg/VelodyneScan"))
    return path


EPOCH = 1_700_000_000  # s


ROWS, COLS = 16, 900


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
    """A rosbag2 bag of PointCloud2 messages on ``/points`` in ``storage`` (sqlite3 or mcap), zstd-compressed per
    message or per file when ``compression`` is ``"MESSAGE"`` or ``"FILE"``."""
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
    """``frames`` room sweeps of ``dtype`` 0.1 s apart as ROS 2 PointCloud2 messages, and their records."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    organised = options.pop("organised", False)
    nan = options.pop("nan", 0.0)
    recs = [room_sweep(dtype, i, organised=organised, nan=nan) for i in range(frames)]
    height = ROWS if organised else 1
    msgs = [ros2_message(ts, r, EPOCH * 10**9 + i * 10**8, height=height, **options) for i, r in enumerate(recs)]
    return msgs, [r.reshape(-1) for r in recs]
