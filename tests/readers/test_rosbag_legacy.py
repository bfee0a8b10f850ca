"""rosbag2 recordings written before message definitions were stored in the bag (Dashing to
Humble: bag format 1-5 metadata without ``type_description_hash``, sqlite3 storage without a
``message_definitions`` table, MCAP files with empty schemas) are read with the standard ROS 2
types and the packet types the reader knows; a topic whose type is neither defined nor known is
refused with one line naming it.

Every fixture is written here: a bag of the current format (with definitions) by ``rosbags``, and
the same messages, byte for byte, in the layout of an older ROS 2 release."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml

from data_tools import open_dataset
from data_tools.errors import DataError
from tests.inputs.rosbags import ros2_sweeps, velodyne_scan_bag, write_ros2
from tests.inputs.velodyne import vlp16_stream

#: rosbag2 sqlite3 schemas of the releases before definitions were stored: Eloquent and before
#: (``topics`` without QoS), Foxy to Humble (``offered_qos_profiles`` added, no ``schema`` table,
#: no ``message_definitions``)
SQLITE_TOPICS = {
    "eloquent": "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, "
    "serialization_format TEXT NOT NULL)",
    "foxy": "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, "
    "serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL)",
}
#: metadata.yaml format version per release (Eloquent 3, Foxy 4, Galactic and Humble 5)
VERSION = {"eloquent": 3, "foxy": 4, "galactic": 5}


def raw_messages(bag: Path) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, log time, serialised bytes) of every message of a rosbag2 folder."""
    from rosbags.rosbag2 import Reader

    with Reader(bag) as r:
        return [(c.topic, c.msgtype, int(t), bytes(raw)) for c, t, raw in r.messages()]


def legacy_metadata(folder: Path, era: str, storage: str, files: list[str], messages: list) -> None:
    """metadata.yaml as the rosbag2 of ``era`` wrote it (no type hash, no ros_distro)."""
    topics: dict[tuple[str, str], int] = {}
    for topic, msgtype, _t, _raw in messages:
        topics[topic, msgtype] = topics.get((topic, msgtype), 0) + 1
    times = [t for _, _, t, _ in messages]
    info = {
        "version": VERSION[era],
        "storage_identifier": storage,
        "relative_file_paths": files,
        "duration": {"nanoseconds": max(times) - min(times)},
        "starting_time": {"nanoseconds_since_epoch": min(times)},
        "message_count": len(messages),
        "topics_with_message_count": [
            {
                "topic_metadata": {"name": topic, "type": msgtype, "serialization_format": "cdr"}
                | ({"offered_qos_profiles": ""} if VERSION[era] >= 4 else {}),
                "message_count": n,
            }
            for (topic, msgtype), n in topics.items()
        ],
        "compression_format": "",
        "compression_mode": "",
    }
    if VERSION[era] >= 5:
        info["files"] = [
            {
                "path": files[0],
                "starting_time": {"nanoseconds_since_epoch": min(times)},
                "duration": {"nanoseconds": max(times) - min(times)},
                "message_count": len(messages),
            }
        ]
    (folder / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False))


def legacy_sqlite_bag(folder: Path, messages: list, era: str = "foxy") -> Path:
    """The ``messages`` as a sqlite3 rosbag2 of ``era`` (no definitions anywhere)."""
    folder.mkdir(parents=True)
    db = sqlite3.connect(folder / f"{folder.name}_0.db3")
    db.execute(SQLITE_TOPICS["eloquent" if era == "eloquent" else "foxy"])
    db.execute(
        "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL, "
        "data BLOB NOT NULL)"
    )
    ids: dict[tuple[str, str], int] = {}
    for topic, msgtype, t, raw in messages:
        if (topic, msgtype) not in ids:
            ids[topic, msgtype] = len(ids) + 1
            qos = [] if era == "eloquent" else [""]
            db.execute(
                f"INSERT INTO topics VALUES (?, ?, ?, 'cdr'{', ?' * len(qos)})",
                [ids[topic, msgtype], topic, msgtype, *qos],
            )
        db.execute("INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)", (ids[topic, msgtype], t, raw))
    db.commit()
    db.close()
    legacy_metadata(folder, era, "sqlite3", [f"{folder.name}_0.db3"], messages)
    return folder


def empty_schema_mcap_bag(folder: Path, messages: list) -> Path:
    """The ``messages`` as an MCAP rosbag2 whose schemas are empty (the schema records name the
    type but hold no definition), with Galactic-era metadata."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        for topic, msgtype, t, raw in messages:
            if (topic, msgtype) not in conns:
                conns[topic, msgtype] = w.add_connection(topic, msgtype, msgdef="", rihs01="RIHS01_" + "0" * 64)
            w.write(conns[topic, msgtype], t, raw)
    (storage,) = [p.name for p in folder.iterdir() if p.suffix == ".mcap"]
    legacy_metadata(folder, "galactic", "mcap", [storage], messages)
    return folder


def legacy_bag(layout: str, folder: Path, messages: list) -> Path:
    if layout == "mcap-empty-schemas":
        return empty_schema_mcap_bag(folder, messages)
    era = layout.split("-")[0]
    return legacy_sqlite_bag(folder, messages, era)


LAYOUTS = ["eloquent-sqlite3", "foxy-sqlite3", "galactic-sqlite3", "mcap-empty-schemas"]
#: a topic of a custom type the reader does not know, recorded without its definition
STATUS = ("/status", "acme_msgs/msg/Status", b"\x00\x01\x00\x00\x07\x00\x00\x00")


@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_bag_without_type_definitions_reads_the_same_clouds(tmp_path, layout):
    """Not 'cannot open recording (damaged or truncated?): Bag contains no type definitions'
    (sqlite3 layouts) or 'damaged or truncated recording (message 0 of topic /points): CDR message size
    mismatch' (MCAP with empty schemas: each type read as an empty structure). A topic
    of an unknown custom type beside the clouds does not stop them from being read."""
    msgs, recs = ros2_sweeps(frames=3)
    modern = write_ros2(tmp_path / "modern", msgs)
    messages = raw_messages(modern)
    messages.append((*STATUS[:2], messages[0][2] + 1, STATUS[2]))
    old = legacy_bag(layout, tmp_path / "old", messages)
    want, got = open_dataset(modern), open_dataset(old)
    assert got.topic == "/points" and len(got) == len(want) == 3
    np.testing.assert_array_equal(got.times, want.times)
    for i, rec in enumerate(recs):
        a, b = want[i], got[i]
        assert b.n_points == a.n_points == len(rec)
        np.testing.assert_array_equal(b.points(), a.points())
        np.testing.assert_array_equal(b.point_slot, a.point_slot)
        np.testing.assert_array_equal(b.point_times(), a.point_times())


@pytest.mark.parametrize("layout", ["foxy-sqlite3", "mcap-empty-schemas"])
def test_raw_velodyne_packets_without_type_definitions_are_decoded(tmp_path, layout):
    """velodyne_msgs/VelodyneScan is not a standard type: before, a Foxy-era bag of packets was
    'damaged' ('cannot open recording', or 'CDR message size mismatch' with empty MCAP schemas). Its
    sweeps are those of the same packets in a bag with definitions."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.3)
    modern = velodyne_scan_bag(tmp_path / "modern", "ros2", payloads, stamps, "/velodyne_packets")
    old = legacy_bag(layout, tmp_path / "old", raw_messages(modern))
    want, got = open_dataset(modern), open_dataset(old)
    assert got.format == "velodyne-pcap" and got.topic == "/velodyne_packets"
    assert len(got) == len(want) >= 2
    np.testing.assert_array_equal(got.times, want.times)
    for i in range(len(want)):
        a, b = want.sweep(i)[1], got.sweep(i)[1]
        for c in ("x", "y", "z", "ring"):
            np.testing.assert_array_equal(b[c], a[c])


@pytest.mark.parametrize("layout", ["foxy-sqlite3", "mcap-empty-schemas"])
def test_a_topic_of_an_unknown_type_without_definition_is_named(tmp_path, layout):
    """Not 'cannot open recording (damaged or truncated?): Bag contains no type definitions.
    Instantiate AnyReader with a default_typestore argument.' (sqlite3), or 'no
    sensor_msgs/PointCloud2 topic' (MCAP). The one line names the topic, its type and what is missing."""
    messages = [("/points", "foo_msgs/msg/Bar", 10**18 + k, STATUS[2]) for k in range(2)]
    old = legacy_bag(layout, tmp_path / "old", messages)
    with pytest.raises(DataError) as exc:
        open_dataset(old)
    msg = str(exc.value)
    assert "\n" not in msg and str(old) in msg, msg
    assert "topic /points has type foo_msgs/msg/Bar with no definition in the recording and none known" in msg
    assert "sensor_msgs/msg/PointCloud2" in msg and "velodyne_msgs/msg/VelodyneScan" in msg


def test_a_definition_stored_as_unknown_is_named_not_called_damage(tmp_path):
    """rosbag2 (Iron on) stores the encoding 'unknown' for a type whose definition it could not
    find while recording; rosbags cannot open such a recording. The error names it, not 'cannot open recording
    (damaged or truncated?): unknown'."""
    msgs, _ = ros2_sweeps(frames=2)
    bag = write_ros2(tmp_path / "bag", msgs)
    (db,) = bag.glob("*.db3")
    with sqlite3.connect(db) as c:
        c.execute("UPDATE message_definitions SET encoding = 'unknown', encoded_message_definition = ''")
    with pytest.raises(DataError) as exc:
        open_dataset(bag)
    msg = str(exc.value)
    assert "\n" not in msg and str(bag) in msg and "damaged" not in msg, msg
    assert "message definition in the encoding 'unknown'" in msg
