"""Open any supported input with automatic format detection."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from data_tools.errors import DataError
from data_tools.sequence import Dataset

log = logging.getLogger("data_tools.datasets")

FORMATS = ("kitti", "ouster", "sim", "ouster-pcap", "velodyne-pcap", "pcd", "las", "rosbag")
# aliases accepted by --format
FORMAT_ALIASES = {"pcap": "ouster-pcap", "ply": "pcd", "bin": "pcd", "laz": "las"}
FORMAT_ALIASES.update({k: "rosbag" for k in ("bag", "mcap", "ros1", "ros2", "db3")})
SWEEP_SUFFIXES = (".pcd", ".ply", ".bin")


def _bag_kind(path: Path) -> str | None:
    from data_tools.rosbag import bag_kind

    return bag_kind(path)


def detect_format(path: str | Path) -> str:
    """Guess the input format of ``path`` (raises :class:`DataError` when unknown)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file or directory")
    if path.is_dir():
        if (path / "sim.json").is_file():
            return "sim"
        if _bag_kind(path) is not None:  # rosbag2 folder (metadata.yaml / .db3), split .bag files
            return "rosbag"
        if (path / "velodyne").is_dir():
            return "kitti"
        if any(path.glob("*.npz")):
            return "ouster"
        if any(f.suffix.lower() in SWEEP_SUFFIXES for f in path.iterdir()):
            return "pcd"
    elif path.suffix == ".npz":
        return "ouster"
    elif _bag_kind(path) is not None:  # .bag, .db3, .mcap, a rosbag2 metadata.yaml
        return "rosbag"
    elif path.suffix.lower() in (".pcap", ".pcapng"):
        from data_tools.ouster_pcap import find_metadata
        from data_tools.velodyne_pcap import check_capture, check_not_hesai, looks_like_velodyne

        check_capture(path)  # an empty or foreign file says so (not "no Ouster metadata")
        if looks_like_velodyne(path):
            return "velodyne-pcap"
        check_not_hesai(path)
        find_metadata(path)  # a pcap without its json: one-line error naming the file
        return "ouster-pcap"
    elif path.suffix.lower() in SWEEP_SUFFIXES:
        return "pcd"
    elif path.suffix.lower() in (".las", ".laz"):
        return "las"
    raise DataError(
        f"{path}: unknown input format (expected a simulated sequence with sim.json, a KITTI directory with "
        "velodyne/, Ouster .npz, an Ouster or Velodyne .pcap, a folder of .pcd/.ply/.bin sweeps, .las/.laz, "
        "a ROS 1 .bag, a ROS 2 .db3 / rosbag2 folder or an .mcap)"
    )


#: the reader options each format takes (an option given for another format is an error, not ignored)
_ORGANISER_OPTIONS = ("rows", "cols", "organize_method")
FORMAT_OPTIONS: dict[str, tuple[str, ...]] = {
    "kitti": _ORGANISER_OPTIONS,
    "ouster": ("destaggered",),
    "sim": (),
    "ouster-pcap": ("meta", "destaggered"),
    "velodyne-pcap": ("model",),
    "pcd": _ORGANISER_OPTIONS,
    "las": _ORGANISER_OPTIONS,
    "rosbag": ("topic", *_ORGANISER_OPTIONS),
}

_OPTION_FLAGS = {"organize_method": "--organize", "destaggered": "--staggered"}


def _organiser(path: Path, options: dict[str, object], **extra: object):
    """An Organizer with the sensor hints given on the command line."""
    from data_tools.organize import Organizer

    rows, cols = options.get("rows"), options.get("cols")
    return Organizer(
        rows=None if rows is None else int(str(rows)),
        cols=None if cols is None else int(str(cols)),
        method=str(options.get("organize_method") or "auto"),
        source_name=str(path),
        **extra,
    )


def open_dataset(path: str | Path, fmt: str | None = None, **options: object) -> Dataset:
    """Open ``path`` as a dataset; ``fmt`` overrides the detected format.

    ``options`` are the readers' options (``topic``, ``meta``, ``model``, ``destaggered``, and the
    organiser's hints ``rows``, ``cols``, ``organize_method``); one that the input's format does not
    take raises :class:`DataError` naming it."""
    fmt = FORMAT_ALIASES.get(fmt, fmt) if fmt else detect_format(path)
    # (destaggered=True is the default: not an option given)
    given = {k: v for k, v in options.items() if v is not None and not (k == "destaggered" and v is True)}
    allowed = FORMAT_OPTIONS.get(fmt)
    if allowed is not None:
        unused = [k for k in given if k not in allowed]
        if unused:
            flags = ", ".join(_OPTION_FLAGS.get(k, "--" + k) for k in unused)
            raise DataError(f"{path}: {flags} does not apply to {fmt} input")
    if fmt == "kitti":
        from data_tools.kitti import KittiSequence

        rows, cols = options.get("rows"), options.get("cols")
        return KittiSequence(
            path,
            rows=None if rows is None else int(str(rows)),
            cols=None if cols is None else int(str(cols)),
            method=str(options.get("organize_method") or "auto"),
        )
    if fmt == "ouster":
        from data_tools.ouster import OusterSequence

        return OusterSequence(path, destaggered=bool(options.get("destaggered", True)))
    if fmt == "sim":
        from data_tools.sim.dataset import SimSequence

        return SimSequence(path)
    if fmt == "ouster-pcap":
        from data_tools.ouster_pcap import OusterPcapSequence

        meta = options.get("meta")
        return OusterPcapSequence(
            path, meta=None if meta is None else str(meta), destaggered=bool(options.get("destaggered", True))
        )
    if fmt == "velodyne-pcap":
        from data_tools.velodyne_pcap import VelodynePcapSequence

        model = options.get("model")
        return VelodynePcapSequence(path, model=None if model is None else str(model))
    if fmt in ("pcd", "las"):
        from data_tools.pcd import SweepFolder

        rows, cols = options.get("rows"), options.get("cols")
        return SweepFolder(
            path,
            rows=None if rows is None else int(str(rows)),
            cols=None if cols is None else int(str(cols)),
            method=str(options.get("organize_method") or "auto"),
        )
    if fmt == "rosbag":
        topic = options.get("topic")
        organizer = None
        if any(k in given for k in _ORGANISER_OPTIONS):
            organizer = _organiser(Path(path), options)
        return open_recording(path, topic=None if topic is None else str(topic), organizer=organizer)
    raise DataError(f"{path}: unsupported format {fmt!r}; choose from {FORMATS}")


def open_recording(path: str | Path, topic: str | None = None, *, organizer: Any = None) -> Dataset:
    """A ROS recording as a dataset: its ``PointCloud2`` topic (:class:`~data_tools.rosbag.RosbagSequence`),
    or, when it holds no PointCloud2 but raw Velodyne packets (``velodyne_msgs/VelodyneScan``), their
    sweeps decoded (:class:`~data_tools.velodyne_pcap.VelodyneScanSequence`)."""
    from data_tools.rosbag import RosbagSequence, velodyne_scan_topics

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
        from data_tools.velodyne_pcap import VelodyneScanSequence

        if organizer is not None:
            log.warning("%s: --rows/--cols/--organize do not apply to raw Velodyne packets; ignored", path)
        return VelodyneScanSequence(path, topic or scans[0])
