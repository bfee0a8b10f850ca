"""Open any supported input with automatic format detection: the registry of readers.

Each format is a :class:`~data_tools.sequence.Reader` (its name, the options it takes, ``detect`` and
``open``), declared by its format module (``READER``); here the simulator's (whose module loads the ray caster)
and the recordings' (a bag holds PointCloud2 sweeps or raw Velodyne packets: two formats).
:func:`detect_format` asks the readers of :func:`readers` in turn; the first that recognises the input
opens it.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from data_tools.errors import DataError
from data_tools.sequence import ORGANISER_OPTIONS, Dataset, Reader, organiser_hints

log = logging.getLogger("data_tools.datasets")

FORMATS = ("kitti", "ouster", "sim", "ouster-pcap", "velodyne-pcap", "pcd", "las", "rosbag")
# aliases accepted by --format
FORMAT_ALIASES = {"pcap": "ouster-pcap", "ply": "pcd", "bin": "pcd", "laz": "las"}
FORMAT_ALIASES.update({k: "rosbag" for k in ("bag", "mcap", "ros1", "ros2", "db3")})
_OPTION_FLAGS = {"organize_method": "--organize", "destaggered": "--staggered"}


def _open_sim(path: Path, options: dict[str, Any]) -> Dataset:
    from data_tools.sim.dataset import SimSequence

    return SimSequence(path)


def _is_recording(path: Path) -> bool:
    from data_tools.formats.rosbag import bag_kind

    return bag_kind(path) is not None  # .bag, .db3, .mcap, a rosbag2 folder or metadata.yaml, split .bag files


def _open_recording(path: Path, options: dict[str, Any]) -> Dataset:
    topic = options.get("topic")
    organizer = None
    if any(options.get(k) is not None for k in ORGANISER_OPTIONS):
        from data_tools.organize import Organizer

        organizer = Organizer(**organiser_hints(options), source_name=str(Path(path)))
    return open_recording(path, topic=None if topic is None else str(topic), organizer=organizer)


SIM = Reader("sim", (), lambda path: path.is_dir() and (path / "sim.json").is_file(), _open_sim)

ROSBAG = Reader("rosbag", ("topic", *ORGANISER_OPTIONS), _is_recording, _open_recording)


def readers() -> tuple[Reader, ...]:
    """Every reader, in the order :func:`detect_format` asks them (a simulated sequence before a
    recording folder before a KITTI directory; a Velodyne capture before an Ouster one)."""
    from data_tools.formats import kitti, ouster, ouster_pcap, pcd, velodyne_pcap

    return (
        SIM,
        ROSBAG,
        kitti.READER,
        ouster.READER,
        velodyne_pcap.READER,
        ouster_pcap.READER,
        pcd.READER,
        pcd.LAS_READER,
    )


def detect_format(path: str | Path) -> str:
    """Guess the input format of ``path`` (raises :class:`DataError` when unknown)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file or directory")
    for reader in readers():
        if reader.detect(path):
            return reader.format
    raise DataError(
        f"{path}: unknown input format (expected a simulated sequence with sim.json, a KITTI directory with "
        "velodyne/, Ouster .npz, an Ouster or Velodyne .pcap, a folder of .pcd/.ply/.bin sweeps, .las/.laz, "
        "a ROS 1 .bag, a ROS 2 .db3 / rosbag2 folder or an .mcap)"
    )


def open_dataset(path: str | Path, fmt: str | None = None, **options: object) -> Dataset:
    """Open ``path`` as a dataset; ``fmt`` overrides the detected format.

    ``options`` are the readers' options (``topic``, ``meta``, ``model``, ``destaggered``, and the
    organiser's hints ``rows``, ``cols``, ``organize_method``); one that the input's format does not
    take raises :class:`DataError` naming it."""
    fmt = FORMAT_ALIASES.get(fmt, fmt) if fmt else detect_format(path)
    reader = next((r for r in readers() if r.format == fmt), None)
    if reader is None:
        raise DataError(f"{path}: unsupported format {fmt!r}; choose from {FORMATS}")
    # (destaggered=True is the default: not an option given)
    given = {k: v for k, v in options.items() if v is not None and not (k == "destaggered" and v is True)}
    unused = [k for k in given if k not in reader.options]
    if unused:
        flags = ", ".join(_OPTION_FLAGS.get(k, "--" + k) for k in unused)
        raise DataError(f"{path}: {flags} does not apply to {fmt} input")
    return reader.open(path, options)


def open_recording(path: str | Path, topic: str | None = None, *, organizer: Any = None) -> Dataset:
    """A ROS recording as a dataset: its ``PointCloud2`` topic (:class:`~data_tools.formats.rosbag.RosbagSequence`),
    or, when it holds no PointCloud2 but raw Velodyne packets (``velodyne_msgs/VelodyneScan``), their
    sweeps decoded (:class:`~data_tools.formats.velodyne_pcap.VelodyneScanSequence`)."""
    from data_tools.formats.rosbag import RosbagSequence, velodyne_scan_topics

    try:
        return RosbagSequence(path, topic, organizer=organizer)
    except DataError:
        scans = velodyne_scan_topics(Path(path))
        if not scans or (topic is not None and topic not in scans):
            raise
        if topic is None and len(scans) > 1:
            raise DataError(
                f"{path}: {len(scans)} VelodyneScan topics, choose one with --topic: {', '.join(sorted(scans))}"
            ) from None
        from data_tools.formats.velodyne_pcap import VelodyneScanSequence

        if organizer is not None:
            log.warning("%s: --rows/--cols/--organize do not apply to raw Velodyne packets; ignored", path)
        return VelodyneScanSequence(path, topic or scans[0])
