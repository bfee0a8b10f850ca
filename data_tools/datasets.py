"""Open any supported input with automatic format detection."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

import numpy as np

from data_tools.errors import DataError
from prc_slam.scan import Scan

FORMATS = ("kitti", "ouster", "sim", "ouster-pcap", "velodyne-pcap", "pcd", "las", "rosbag")
# aliases accepted by --format
FORMAT_ALIASES = {"pcap": "ouster-pcap", "ply": "pcd", "bin": "pcd", "laz": "las"}
FORMAT_ALIASES.update({k: "rosbag" for k in ("bag", "mcap", "ros1", "ros2", "db3")})
SWEEP_SUFFIXES = (".pcd", ".ply", ".bin")


class Dataset(Protocol):
    """A sequence of Scans with optional ground-truth poses and frame times."""

    format: str
    name: str
    poses: np.ndarray | None
    times: np.ndarray | None

    def __len__(self) -> int: ...
    def __getitem__(self, i: int) -> Scan: ...
    def __iter__(self) -> Iterator[Scan]: ...


class SequenceBase:
    """Indexable, iterable sequence of Scans; subclasses implement ``__getitem__`` over ``files``."""

    files: list[Path]

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self) -> Iterator[Scan]:
        for i in range(len(self)):
            yield self[i]

    def __getitem__(self, i: int) -> Scan:
        raise NotImplementedError


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
        from data_tools.velodyne_pcap import looks_like_velodyne

        if looks_like_velodyne(path):
            return "velodyne-pcap"
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


def open_dataset(path: str | Path, fmt: str | None = None, **options: object) -> Dataset:
    """Open ``path`` as a dataset; ``fmt`` overrides the detected format."""
    fmt = FORMAT_ALIASES.get(fmt, fmt) if fmt else detect_format(path)
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

        return OusterSequence(path, destaggered=bool(options.get("destaggered", False)))
    if fmt == "sim":
        from data_tools.sim.dataset import SimSequence

        return SimSequence(path)
    if fmt == "ouster-pcap":
        from data_tools.ouster_pcap import OusterPcapSequence

        meta = options.get("meta")
        return OusterPcapSequence(
            path, meta=None if meta is None else str(meta), destaggered=bool(options.get("destaggered", False))
        )
    if fmt == "velodyne-pcap":
        from data_tools.velodyne_pcap import VelodynePcapSequence

        model = options.get("model")
        return VelodynePcapSequence(path, model=None if model is None else str(model))
    if fmt in ("pcd", "las"):
        from data_tools.pcd import SweepFolder

        rows, cols = options.get("rows"), options.get("cols")
        return SweepFolder(
            path, rows=None if rows is None else int(str(rows)), cols=None if cols is None else int(str(cols))
        )
    if fmt == "rosbag":
        from data_tools.rosbag import RosbagSequence

        topic = options.get("topic")
        return RosbagSequence(path, topic=None if topic is None else str(topic))
    raise DataError(f"{path}: unsupported format {fmt!r}; choose from {FORMATS}")
