"""ROS 1 ``.bag``, ROS 2 (``.db3`` / rosbag2 folder) and ``.mcap`` recordings of ``sensor_msgs/PointCloud2``.

Read with ``rosbags`` (pure Python, no ROS installation). One cloud topic is read per sequence:
detected when the recording holds exactly one ``PointCloud2`` topic, chosen with ``topic=``
otherwise (the error lists the candidates). ROS 1 chunks may be bz2 / lz4 compressed, rosbag2
messages or files zstd compressed: a compressed rosbag2 storage file given alone is read through
its folder's ``metadata.yaml`` (which alone says it is compressed). Recordings without message
definitions (rosbag2 before Iron: bag format 1-7 metadata, sqlite3 storage without
``message_definitions``, MCAP files with empty schemas) are read with the standard ROS 2 types and
the packet types of :data:`PACKET_DEFINITIONS` (:func:`open_reader`); a topic whose type is
neither defined nor known is refused, naming it.

The messages are decoded and organised by :mod:`data_tools.formats.pointcloud2`.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from data_tools.errors import DataError
from data_tools.formats.pointcloud2 import (  # noqa: F401 (also importable from here)
    DATATYPE_CODES,
    POINTCLOUD2,
    CloudMessage,
    Field,
    TimeField,
    cloud_from_records,
    cloud_to_scan,
    cloud_xyz,
    decode_cloud,
    detect_time_field,
    fields_dtype,
    time_unit,
)
from prc_slam.scan import Scan

log = logging.getLogger("prc_slam.rosbag")

#: Suffixes of rosbag2 storage files compressed whole (``ros2 bag record --compression-mode file``).
COMPRESSED_SUFFIXES = (".db3.zstd", ".mcap.zstd")
#: First bytes of a zstd frame (a message of a message-compressed rosbag2 read without its metadata).
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


# --------------------------------------------------------------------------------------------
# recordings


def bag_kind(path: str | Path) -> str | None:
    """``ros1``, ``ros2`` or ``mcap`` when ``path`` looks like a recording, else None.

    A ``.bag`` file (or a folder of split ``.bag`` files) is ROS 1; a ``.db3`` file (``.db3.zstd``,
    ``.mcap.zstd``: compressed whole), a folder holding ``metadata.yaml`` or a ``.db3`` is ROS 2; a
    ``.mcap`` file is MCAP.
    """
    path = Path(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "ros2"
        if any(path.glob("*.db3")):
            return "ros2"
        if any(path.glob("*.bag")):
            return "ros1"
        if any(path.glob("*.mcap")):
            return "mcap"
        return None
    if path.name == "metadata.yaml" or path.name.lower().endswith(COMPRESSED_SUFFIXES):
        return "ros2"
    return {".bag": "ros1", ".db3": "ros2", ".mcap": "mcap"}.get(path.suffix.lower())


def reader_paths(path: Path) -> list[Path]:
    """The paths to hand to ``AnyReader`` for a recording ``path`` (see :class:`RosbagSequence`)."""
    path = Path(path)
    kind = bag_kind(path)
    if kind is None:
        raise DataError(f"{path}: not a ROS 1 .bag, ROS 2 .db3 / rosbag2 folder or .mcap recording")
    return _reader_paths(path, kind)


VELODYNE_SCAN = ("velodyne_msgs/msg/VelodyneScan", "velodyne_msgs/VelodyneScan")

#: Definitions (``.msg``) of the packet messages read or recognised in recordings, for the
#: recordings that do not carry them: raw Velodyne packets (velodyne_msgs, decoded by
#: :class:`~data_tools.formats.velodyne_pcap.VelodyneScanSequence`) and raw Ouster packets (ouster-ros 1
#: and 2, recognised with a hint). Time is ``builtin_interfaces/Time`` in both ROS versions (ROS 1
#: ``time`` deserialises to it).
PACKET_DEFINITIONS = {
    "velodyne_msgs/msg/VelodynePacket": "builtin_interfaces/Time stamp\nuint8[1206] data\n",
    "velodyne_msgs/msg/VelodyneScan": "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets\n",
    "ouster_sensor_msgs/msg/PacketMsg": "uint8[] buf\n",
    "ouster_ros/msg/PacketMsg": "uint8[] buf\n",
}
#: The standard message types a recording without its own definitions is read with (``rosbags``
#: type stores). The types read here (PointCloud2, Header, Time, the packets) are the same from
#: ROS 2 Dashing to Jazzy; ROS 1 recordings always carry their definitions.
KNOWN_STORES = {True: "ROS2_HUMBLE", False: "ROS1_NOETIC"}


@functools.cache
def known_types(ros2: bool = True) -> Any:
    """The ``rosbags`` typestore of the message types known without a recording's definitions:
    the standard ROS 2 (or ROS 1) types of :data:`KNOWN_STORES` and the packets of
    :data:`PACKET_DEFINITIONS`. Shared: read it, never register into it."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(getattr(Stores, KNOWN_STORES[ros2]))
    types: dict[str, Any] = {}
    for name, text in PACKET_DEFINITIONS.items():
        types.update(get_types_from_msg(text, name))
    store.register({k: v for k, v in types.items() if k not in store.fielddefs})
    return store


def describe_known_types(ros2: bool = True) -> str:
    """The known types in a few words (for an error naming a type that is not among them)."""
    store = KNOWN_STORES[ros2].replace("_", " ").title().replace("Ros", "ROS ")
    return f"sensor_msgs/msg/PointCloud2, {', '.join(PACKET_DEFINITIONS)} and the other standard {store} messages"


def _has_definition(conn: Any) -> bool:
    """The connection carries a message definition (not none, not an empty one: some MCAP
    writers stored empty schemas)."""
    from rosbags.interfaces import MessageDefinitionFormat

    return conn.msgdef.format != MessageDefinitionFormat.NONE and bool(conn.msgdef.data.strip())


def _dependencies(names: set[str], fielddefs: dict[str, Any]) -> set[str]:
    """``names`` and every type their fields use, transitively (names found in ``fielddefs``)."""
    out: set[str] = set()
    todo = [n for n in names if n in fielddefs]
    while todo:
        name = todo.pop()
        if name in out:
            continue
        out.add(name)
        stack: list[Any] = [fielddefs[name]]
        while stack:
            item = stack.pop()
            if isinstance(item, str):
                if item in fielddefs and item not in out:
                    todo.append(item)
            elif isinstance(item, tuple | list):
                stack.extend(item)
    return out


def complete_types(store: Any, connections: Sequence[Any], known: Any) -> Any:
    """The typestore of a recording with the types its connections lack a definition for taken
    from ``known`` (an empty definition counts as none: it would decode every message as an empty
    structure). A type neither defined nor known stays missing (reading its topic is then refused,
    naming it). Returns ``store`` itself when nothing is to be added."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_typestore

    if all(c.msgdef.format == MessageDefinitionFormat.NONE for c in connections):
        return store  # rosbags read the recording with ``known`` as its default typestore
    defined = {c.msgtype for c in connections if _has_definition(c)}
    lacking = {c.msgtype for c in connections} - defined
    wanted = {n for n in lacking if n in known.fielddefs}
    if not wanted and not (lacking & set(store.fielddefs)):
        return store
    types = {n: d for n, d in store.fielddefs.items() if n not in lacking}
    types.update(
        {n: known.fielddefs[n] for n in _dependencies(wanted, known.fielddefs) if n not in types or n in wanted}
    )
    fresh = get_typestore(Stores.EMPTY)
    fresh.register(types)
    return fresh


def undefined_types(reader: Any) -> dict[str, str]:
    """Topic -> type of the topics whose type has no definition, neither in the recording nor
    among the known types (their messages cannot be decoded)."""
    have = reader.typestore.fielddefs
    return {c.topic: c.msgtype for c in reader.connections if c.msgtype not in have}


def open_reader(paths: Sequence[Path]) -> Any:
    """An (unopened) ``rosbags`` reader of ``paths`` that also reads recordings without message
    definitions (rosbag2 before Iron: bag format 4-7, sqlite3 without ``message_definitions``,
    MCAP files with empty schemas): the types they lack are taken from :func:`known_types`. Use it
    as a context manager, or call ``open()``."""
    from rosbags.highlevel import AnyReader

    class _Reader(AnyReader):
        def open(self) -> None:
            super().open()
            try:
                self.typestore = complete_types(self.typestore, self.connections, known_types(self.is2))
            except BaseException:
                self.close()
                raise

    reader = _Reader(paths)
    reader.default_typestore = known_types(reader.is2)
    return reader


def velodyne_scan_topics(path: Path) -> list[str]:
    """The topics of raw Velodyne packets (``velodyne_msgs/VelodyneScan``) in a recording (none
    when it cannot be read: the PointCloud2 reader's error then stands)."""
    try:
        with open_reader(reader_paths(path)) as reader:
            return sorted(n for n, info in reader.topics.items() if info.msgtype in VELODYNE_SCAN)
    except Exception:  # the PointCloud2 reader's error stands
        return []


def _compressed_bag_folder(path: Path) -> Path | None:
    """The rosbag2 folder of the storage file ``path`` when its ``metadata.yaml`` lists the file
    and says its messages or the file are compressed (readable only through the folder), else None."""
    meta = path.parent / "metadata.yaml"
    if not meta.is_file():
        return None
    try:
        import yaml

        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        listed = {Path(str(p)).name for p in info.get("relative_file_paths") or []}
        compressed = str(info.get("compression_mode") or "none").lower() not in ("", "none")
    except Exception:  # not a rosbag2 metadata file: the storage file is read alone
        return None
    return path.parent if compressed and path.name in listed else None


def _reader_paths(path: Path, kind: str) -> list[Path]:
    """Paths to hand to ``AnyReader`` (a compressed rosbag2 storage file: its folder).

    Raises
    ------
    DataError
        A storage file compressed whole without the ``metadata.yaml`` that lists it; several
        ``.db3`` / ``.mcap`` files in a folder without one.
    """
    if path.name == "metadata.yaml":
        return [path.parent]
    if path.is_file() and kind != "ros1":
        folder = _compressed_bag_folder(path)
        if folder is not None:
            return [folder]
        if path.name.lower().endswith(COMPRESSED_SUFFIXES):
            raise DataError(
                f"{path}: a rosbag2 file compressed whole (zstd) is read through the metadata.yaml of its folder, "
                f"which is missing or does not list it; give the rosbag2 folder, or decompress it (zstd -d)"
            )
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return [path]
        for pattern in ("*.db3", "*.mcap"):
            files = sorted(path.glob(pattern))
            if len(files) == 1:
                return files
            if len(files) > 1:
                raise DataError(
                    f"{path}: {len(files)} {pattern[1:]} files without a metadata.yaml; open one of them "
                    f"({', '.join(f.name for f in files[:4])}{', ...' if len(files) > 4 else ''})"
                )
        return sorted(path.glob("*.bag"))
    return [path]


def _open_error(path: Path, kind: str, exc: BaseException) -> str:
    """The one-line error of a recording that cannot be opened. A ``KeyError`` of a string is
    ``rosbags`` meeting a message-definition encoding it does not know: rosbag2 stores
    ``unknown`` (with no text) for a type whose definition it could not find while recording."""
    if isinstance(exc, KeyError) and exc.args and isinstance(exc.args[0], str):
        return (
            f"{path}: cannot open recording: it stores a message definition in the encoding {exc.args[0]!r}, "
            "which the rosbags reader does not know (rosbag2 writes 'unknown' for a type whose definition it "
            "could not find while recording)"
        )
    hint = " (an unindexed ROS 1 bag is repaired by `rosbag reindex`)" if kind == "ros1" else ""
    return f"{path}: cannot open recording (damaged or truncated?): {_describe_error(exc)}{hint}"


def _describe_error(exc: BaseException) -> str:
    text = " ".join(str(a) for a in exc.args) or type(exc).__name__
    return " ".join(text.split())[:300]


class RosbagSequence:
    """A ``PointCloud2`` topic of a ROS 1 / ROS 2 / MCAP recording as a sequence of Scans.

    The messages are indexed once on opening (log time, header stamp); ``__getitem__`` seeks
    to a message by its log time, ``__iter__`` streams the topic in order. One
    :class:`~data_tools.organize.Organizer` serves the whole sequence (beam table and column
    count estimated once and reused).

    Parameters
    ----------
    path : ``.bag``, ``.db3``, ``.mcap``, a rosbag2 folder (``metadata.yaml``) or its
        ``metadata.yaml``, or a folder of split ``.bag`` files
    topic : str, optional
        Required when the recording holds several ``PointCloud2`` topics.

    Attributes
    ----------
    format : ``"rosbag"``
    kind : ``"ros1"``, ``"ros2"`` or ``"mcap"``
    topic, msgtype : the topic read and its message type name
    times : float64 (n,) header stamps (s)
    log_times : int64 (n,) recording (log) times (ns)
    poses : None
    """

    format = "rosbag"

    def __init__(self, path: str | Path, topic: str | None = None, *, organizer: Any = None) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise DataError(f"{self.path}: no such file or directory")
        kind = bag_kind(self.path)
        if kind is None:
            raise DataError(f"{self.path}: not a ROS 1 .bag, ROS 2 .db3 / rosbag2 folder or .mcap recording")
        self.kind = kind
        self.storage = "mcap" if kind == "mcap" else ("sqlite3" if kind == "ros2" else "ros1")
        paths = _reader_paths(self.path, kind)
        if not paths:
            raise DataError(f"{self.path}: no recording files found")
        if paths[0].is_dir() and (paths[0] / "metadata.yaml").is_file():
            if any(paths[0].glob("*.mcap")) or any(paths[0].glob("*.mcap.zstd")):
                self.storage = "mcap"
        elif paths[0].suffix.lower() == ".mcap":
            self.kind = "mcap"
            self.storage = "mcap"
        self.name = self.path.stem if self.path.is_file() else self.path.name
        self.poses = None
        self._reader = None
        try:
            self._reader = open_reader(paths)
            self._reader.open()
        except Exception as exc:  # rosbags raises many types for damaged files
            self._reader = None
            raise DataError(_open_error(self.path, kind, exc)) from exc
        self._ros1 = not self._reader.is2
        try:
            self.topic, self.msgtype = self._choose_topic(topic)
            self._connections = [
                c for c in self._reader.connections if c.topic == self.topic and _is_pointcloud2(c.msgtype)
            ]
            others = sorted({c.msgtype for c in self._reader.connections if c.topic == self.topic} - {self.msgtype})
            if others:
                log.warning(
                    "%s: topic %s also carries %s messages (another publisher); only its PointCloud2 messages are read",
                    self.path,
                    self.topic,
                    ", ".join(others),
                )
            self._index()
        except BaseException:
            self.close()
            raise
        period = float(np.median(np.diff(self.times))) if len(self.times) > 1 else None
        self.period = period if period and period > 0 else None
        self._time_field: TimeField | bool | None = False  # False: not yet decided
        self._organizer = organizer
        self._row_lines: dict[tuple[int, int], bool] = {}  # organised grid shape -> rows are scan lines
        self._units_checked = False  # the first cloud read is checked for metres and its frame

    @property
    def organizer(self) -> Any:
        """The sequence's :class:`~data_tools.organize.Organizer` (created on first use)."""
        if self._organizer is None:
            from data_tools.organize import Organizer

            self._organizer = Organizer(source_name=str(self.path), sweep_period=self.period or 0.1)
        return self._organizer

    # -- opening -----------------------------------------------------------------------------

    def _topic_types(self) -> dict[str, list[str]]:
        """Each topic's message types, from its connections (publishers of one topic may send
        several types; rosbags then gives the topic no type)."""
        types: dict[str, set[str]] = {}
        for c in self._reader.connections:
            types.setdefault(c.topic, set()).add(str(c.msgtype))
        return {name: sorted(t) for name, t in types.items()}

    def _choose_topic(self, topic: str | None) -> tuple[str, str]:
        """The PointCloud2 topic to read (``topic``, or the only one) and its type name."""
        types = self._topic_types()
        clouds = {name: m for name, t in types.items() for m in t if _is_pointcloud2(m)}
        undefined = undefined_types(self._reader)
        if topic is not None:
            if topic in undefined:
                raise DataError(self._undefined(topic, undefined[topic]))
            if topic not in clouds:
                all_topics = sorted(self._reader.topics)
                raise DataError(
                    f"{self.path}: no PointCloud2 topic {topic!r}; cloud topics: {sorted(clouds) or 'none'}"
                    + ("" if clouds else f" (topics: {all_topics})")
                )
            return topic, clouds[topic]
        if not clouds and undefined:
            raise DataError("; ".join(self._undefined(t, m) for t, m in sorted(undefined.items())))
        if not clouds:
            listed = ", ".join(f"{n} ({' + '.join(t)})" for n, t in sorted(types.items())[:8]) or "none"
            hints = "".join(f"; {n} holds {_hint(m)}" for n, t in sorted(types.items())[:8] for m in t if _hint(m))
            raise DataError(f"{self.path}: no sensor_msgs/PointCloud2 topic (topics: {listed}){hints}")
        if len(clouds) > 1:
            raise DataError(
                f"{self.path}: {len(clouds)} PointCloud2 topics, choose one with --topic: {', '.join(sorted(clouds))}"
            )
        name = next(iter(clouds))
        return name, clouds[name]

    def _undefined(self, topic: str, msgtype: str) -> str:
        """Why ``topic`` cannot be read: its type has no definition, in the recording or known."""
        return (
            f"{self.path}: topic {topic} has type {msgtype} with no definition in the recording and none known "
            f"(known types: {describe_known_types(not self._ros1)})"
        )

    def _index(self) -> None:
        """One pass over the topic: log times and header stamps of every message."""
        log_times: list[int] = []
        stamps: list[float] = []
        fast = False
        raw: bytes | memoryview = b""
        try:
            for conn, t, raw in self._reader.messages(connections=self._connections):
                if not log_times:  # the layout is checked on opening (fields, sizes)
                    msg = self._reader.deserialize(raw, conn.msgtype)
                    decode_cloud(msg, self._source(0))
                    stamp = int(msg.header.stamp.sec) + int(msg.header.stamp.nanosec) * 1e-9
                    fast = _raw_stamp(raw, self._ros1) == stamp
                elif fast:
                    stamp = _raw_stamp(raw, self._ros1)
                else:
                    msg = self._reader.deserialize(raw, conn.msgtype)
                    stamp = int(msg.header.stamp.sec) + int(msg.header.stamp.nanosec) * 1e-9
                log_times.append(int(t))
                stamps.append(stamp)
        except DataError:
            raise
        except Exception as exc:
            if bytes(raw[:4]) == ZSTD_MAGIC:
                raise DataError(
                    f"{self.path}: the messages of {self.topic} are zstd-compressed (rosbag2 message compression), "
                    "which only the bag's metadata.yaml says: give the rosbag2 folder with its metadata.yaml"
                ) from exc
            raise DataError(
                f"{self.path}: damaged or truncated recording (message {len(log_times)} of topic {self.topic}): "
                f"{_describe_error(exc)}"
            ) from exc
        if not log_times:
            raise DataError(f"{self.path}: topic {self.topic} holds no messages")
        self.log_times = np.asarray(log_times, dtype=np.int64)
        self.times = np.asarray(stamps, dtype=np.float64)
        self.stamps_from_log = False  # header stamps unset: frame times are the log times
        if len(self.times) > 1 and (self.times == self.times[0]).all() and (np.diff(self.log_times) > 0).all():
            log.warning(
                "%s: all %d header stamps of %s are %.6f s (unset by the driver?); the frames are timed by the "
                "recording's log times instead (%.6f s to %.6f s)",
                self.path,
                len(self.times),
                self.topic,
                self.times[0],
                self.log_times[0] * 1e-9,
                self.log_times[-1] * 1e-9,
            )
            self.stamps_from_log = True
            self.times = self.log_times * 1e-9
        stuck = np.flatnonzero(np.diff(self.times) <= 0) + 1
        if len(stuck):  # odometry needs increasing frame times: say so before it stops there
            k = int(stuck[0])
            log.warning(
                "%s: %d of %d header stamps of %s do not increase (first: message %d at %.6f s after %.6f s); "
                "odometry stops at such a frame",
                self.path,
                len(stuck),
                len(self.times),
                self.topic,
                k,
                self.times[k],
                self.times[k - 1],
            )
        # position of each message among those sharing its log time (for seeking)
        self._dup = np.zeros(len(log_times), dtype=np.int64)
        for i in range(1, len(log_times)):
            if log_times[i] == log_times[i - 1]:
                self._dup[i] = self._dup[i - 1] + 1

    def close(self) -> None:
        """Close the recording (idempotent; also of one whose opening failed early)."""
        if getattr(self, "_reader", None) is not None:
            try:
                self._reader.close()
            except Exception:  # closing a damaged file must not mask the real error
                pass
            self._reader = None

    def __del__(self) -> None:
        self.close()

    def __enter__(self) -> RosbagSequence:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading -------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.log_times)

    def _source(self, i: int) -> str:
        return f"{self.path}#{self.topic}[{i}]"

    def decode(self, i: int, raw: bytes, msgtype: str) -> CloudMessage:
        """Deserialise and decode message ``i``."""
        try:
            msg = self._reader.deserialize(raw, msgtype)
        except Exception as exc:
            raise DataError(f"{self._source(i)}: cannot deserialise PointCloud2: {_describe_error(exc)}") from exc
        return decode_cloud(msg, self._source(i))

    def _scan(self, i: int, cloud: CloudMessage) -> Scan:
        if self._time_field is False:
            self._time_field = detect_time_field(cloud, self.period)
            if self._time_field is not None:
                log.info("%s: per-point time from field %s", self.path, self._time_field.describe())
        tf = self._time_field if isinstance(self._time_field, TimeField) else None
        if not self._units_checked:  # the first cloud read: in metres, in its sensor's frame?
            self._units_checked = True
            from data_tools.units import warn_unless_metres

            warn_unless_metres(cloud_xyz(cloud), f"{self.path} ({self.topic}, frame {cloud.frame_id!r})", "clouds")
        timed = cloud
        if self.stamps_from_log:  # organised at the log time; the message itself is kept as recorded
            sec, nsec = divmod(int(self.log_times[i]), 10**9)
            timed = dataclasses.replace(cloud, stamp_sec=sec, stamp_nanosec=nsec)
        scan = cloud_to_scan(
            timed, self.organizer, name=f"{i:06d}", source=self._source(i), time_field=tf, row_lines=self._row_lines
        )
        scan.meta["ros"] = cloud
        scan.meta["log_time_ns"] = int(self.log_times[i])
        scan.meta["topic"] = self.topic
        scan.meta["frame_index"] = i
        return scan

    def __getitem__(self, i: int) -> Scan:
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"{self.path}: frame {i} out of range ({n} frames)")
        self._check_open()
        t = int(self.log_times[i])
        k = int(self._dup[i])
        found = None
        try:
            for j, (conn, _t, raw) in enumerate(
                self._reader.messages(connections=self._connections, start=t, stop=t + 1)
            ):
                if j == k:
                    found = (conn.msgtype, raw)
                    break
        except Exception as exc:
            raise DataError(f"{self._source(i)}: cannot read message: {_describe_error(exc)}") from exc
        if found is None:
            raise DataError(f"{self._source(i)}: message vanished from the recording")
        return self._scan(i, self.decode(i, found[1], found[0]))

    def clouds(self) -> Iterator[tuple[int, CloudMessage]]:
        """Stream the topic as decoded clouds (log time in ns, cloud), without organising."""
        self._check_open()
        stream = self._reader.messages(connections=self._connections)
        for i in range(len(self)):
            try:
                conn, t, raw = next(stream)
            except StopIteration:
                raise DataError(f"{self.path}: topic {self.topic} ended after {i} of {len(self)} messages") from None
            except Exception as exc:
                raise DataError(f"{self._source(i)}: cannot read message: {_describe_error(exc)}") from exc
            yield int(t), self.decode(i, raw, conn.msgtype)

    def __iter__(self) -> Iterator[Scan]:
        """Stream the topic as Scans. A message that cannot be decoded or organised raises
        :class:`DataError` for that frame only: iteration can go on with the next message (a
        caller that skips bad frames loses nothing else). A damaged stream ends iteration."""
        self._check_open()
        return _ScanIterator(self)

    def _check_open(self) -> None:
        if self._reader is None:
            raise DataError(f"{self.path}: recording is closed")


class _ScanIterator:
    """Iterator of :meth:`RosbagSequence.__iter__` (survives a bad frame, unlike a generator)."""

    def __init__(self, seq: RosbagSequence) -> None:
        self.seq = seq
        self.stream = seq._reader.messages(connections=seq._connections)
        self.i = 0
        self.done = False

    def __iter__(self) -> _ScanIterator:
        return self

    def __next__(self) -> Scan:
        seq, i = self.seq, self.i
        if self.done or i >= len(seq):
            raise StopIteration
        try:
            conn, _t, raw = next(self.stream)
        except StopIteration:
            self.done = True
            raise DataError(f"{seq.path}: topic {seq.topic} ended after {i} of {len(seq)} messages") from None
        except Exception as exc:
            self.done = True
            raise DataError(f"{seq._source(i)}: cannot read message: {_describe_error(exc)}") from exc
        self.i += 1
        return seq._scan(i, seq.decode(i, raw, conn.msgtype))


def _raw_stamp(raw: bytes | memoryview, ros1: bool) -> float | None:
    """Header stamp (s) read straight from a serialised message (checked against the full
    deserialisation on the first message): ROS 1 ``seq, sec, nsec`` (little endian); CDR a
    4-byte encapsulation header (byte 1: 0 big, 1 little endian), then ``sec, nanosec``."""
    b = bytes(raw[:12])
    if len(b) < 12:
        return None
    if ros1:
        sec, nsec = int.from_bytes(b[4:8], "little"), int.from_bytes(b[8:12], "little")
    else:
        order = "little" if b[1] & 1 else "big"
        sec, nsec = int.from_bytes(b[4:8], order, signed=True), int.from_bytes(b[8:12], order)
    return sec + nsec * 1e-9


#: Message types that hold a lidar's data in another form than PointCloud2 -> what to do with them.
OTHER_LIDAR_TYPES = {
    "velodyne_msgs/msg/VelodyneScan": "raw Velodyne packets: data_tools.open_dataset and the command line "
    "decode them (data_tools.formats.velodyne_pcap.VelodyneScanSequence)",
    "ouster_sensor_msgs/msg/PacketMsg": "raw Ouster packets: convert them with ouster-ros or read a .pcap with "
    "its metadata json",
    "ouster_ros/msg/PacketMsg": "raw Ouster packets: convert them with ouster-ros or read a .pcap with its "
    "metadata json",
    "pandar_msgs/msg/PandarScan": "raw Hesai packets: convert them to PointCloud2 with the Hesai driver",
    "livox_ros_driver/msg/CustomMsg": "Livox CustomMsg points: record PointCloud2 instead (livox driver xfer_format 0)",
    "livox_ros_driver2/msg/CustomMsg": "Livox CustomMsg points: record PointCloud2 instead (livox driver "
    "xfer_format 0)",
    "sensor_msgs/msg/PointCloud": "the old sensor_msgs/PointCloud: convert it to PointCloud2 (point_cloud_converter)",
    "sensor_msgs/msg/LaserScan": "2-D laser scans, not a 3-D lidar",
}


def _hint(msgtype: str) -> str | None:
    """What a topic of ``msgtype`` holds and how to read it, when it is a lidar's data in another form."""
    return OTHER_LIDAR_TYPES.get(msgtype.replace("/msg/", "/").replace("/", "/msg/", 1))


def _is_pointcloud2(msgtype: str | None) -> bool:
    return msgtype in (POINTCLOUD2, "sensor_msgs/PointCloud2")
