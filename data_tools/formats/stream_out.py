"""Writers of a filtered point stream, one frame at a time: ROS 1 ``.bag``, ROS 2 bag, ``.mcap``,
a folder of ``.pcd`` sweeps or KITTI bins.

Every writer takes, per frame, the :class:`~prc_slam.scan.Scan` it came from, the mask of the
points kept (one entry per input point, input order) and the label of every input point, and
writes the kept points with their label:

- ``ros1`` / ``ros2`` / ``mcap``: a ``sensor_msgs/PointCloud2`` on the input's topic, with the
  input's frame id, header stamp, log time and every input field byte for byte (offsets,
  datatypes, byte order and padding kept), plus a ``label`` field (``uint8`` by default,
  ``uint16`` on request; ``prc_label`` when the input already has a ``label``) appended after
  the input's ``point_step``. The output cloud is unorganised (``height = 1``). Needs a Scan
  read from a recording (``meta["ros"]``);
- ``pcd``: ``NNNNNN.pcd`` (binary, unorganised) with the input's own fields when it has them
  (a recording's PointCloud2 fields, a PCD/PLY folder's fields) plus ``label``, else
  ``x y z [intensity] [time] label`` (``time`` in s from the frame time); ``times.txt``;
- ``kitti``: ``velodyne/NNNNNN.bin`` (float32 x y z intensity), ``labels/NNNNNN.label``
  (uint32, our code in the lower 16 bits), ``times.txt``, ``poses.txt`` and an identity
  ``calib.txt`` when the input has poses.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from data_tools.errors import DataError
from data_tools.formats.pcd import write_pcd
from data_tools.formats.pointcloud2 import DATATYPE_CODES, POINTCLOUD2, CloudMessage, Field
from data_tools.formats.rosbag import bag_kind
from prc_slam import labels as L
from prc_slam.scan import Scan

OUT_FORMATS = ("mcap", "ros2", "ros1", "pcd", "kitti")


class StreamWriter:
    """Base: a context manager with ``write(scan, keep, labels)``; ``frames`` counts frames."""

    format = ""

    def __init__(self, out: str | Path) -> None:
        self.out = Path(out)
        self.frames = 0
        self.points = 0

    def write(self, scan: Scan, keep: np.ndarray, labels: np.ndarray) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Finish the output (idempotent)."""

    def __enter__(self) -> StreamWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close()

    @staticmethod
    def _check(scan: Scan, keep: np.ndarray, labels: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        keep = np.asarray(keep, dtype=bool)
        labels = np.asarray(labels)
        if keep.shape != (n,) or labels.shape != (n,):
            raise DataError(f"{scan.source}: {keep.shape} keep flags and {labels.shape} labels for {n} input points")
        return keep, labels


def _check_new(path: Path, overwrite: bool) -> None:
    if path.exists() or path.is_symlink():
        if not overwrite:
            raise DataError(f"{path}: exists already (choose another --out or remove it)")
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


# --------------------------------------------------------------------------------------------
# ROS 1 / ROS 2 / MCAP


class RosCloudWriter(StreamWriter):
    """Filtered ``PointCloud2`` messages into a ``.bag`` (``ros1``), a rosbag2 folder (``ros2``,
    sqlite3 or MCAP storage) or a single ``.mcap`` file (``mcap``).

    Parameters
    ----------
    out : output path (created; must not exist unless ``overwrite``)
    kind : ``ros1``, ``ros2`` or ``mcap``
    topic : topic of the output messages (the input's)
    storage : for ``ros2``: ``sqlite3`` (default) or ``mcap``
    label_dtype : ``uint8`` or ``uint16``
    """

    def __init__(
        self,
        out: str | Path,
        kind: str,
        topic: str,
        *,
        storage: str = "sqlite3",
        label_dtype: str = "uint8",
        overwrite: bool = False,
    ) -> None:
        super().__init__(out)
        from rosbags.typesys import Stores, get_typestore

        if kind not in ("ros1", "ros2", "mcap"):
            raise DataError(f"{out}: unknown recording kind {kind!r}")
        if label_dtype not in ("uint8", "uint16"):
            raise DataError(f"{out}: label field type must be uint8 or uint16, got {label_dtype!r}")
        self.kind = kind
        self.format = kind
        self.topic = topic
        self.label_dtype = np.dtype(label_dtype)
        self._label_code = DATATYPE_CODES[self.label_dtype.str[1:]]
        _check_new(self.out, overwrite)
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self._typestore = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
        self._types = self._typestore.types
        self._tmp: Path | None = None
        try:
            if kind == "ros1":
                from rosbags.rosbag1 import Writer as Writer1

                self._writer = Writer1(self.out)
                self._writer.open()
                self._conn = self._writer.add_connection(topic, POINTCLOUD2, typestore=self._typestore)
            else:
                from rosbags.rosbag2 import StoragePlugin
                from rosbags.rosbag2 import Writer as Writer2

                target = self.out
                plugin = StoragePlugin.SQLITE3
                if kind == "mcap" or storage == "mcap":
                    plugin = StoragePlugin.MCAP
                if kind == "mcap":  # rosbag2 writes a folder; the .mcap inside is moved to ``out``
                    self._tmp = self.out.parent / f".{self.out.name}.tmp"
                    _check_new(self._tmp, True)
                    target = self._tmp
                self._writer = Writer2(target, version=9, storage_plugin=plugin)
                self._writer.open()
                self._conn = self._writer.add_connection(topic, POINTCLOUD2, typestore=self._typestore)
        except DataError:
            raise
        except Exception as exc:
            raise DataError(f"{self.out}: cannot create {kind} output: {exc}") from exc
        self._open = True

    def message(self, cloud: CloudMessage, keep: np.ndarray, labels: np.ndarray) -> Any:
        """The output ``PointCloud2``: kept points, all input fields and the label field."""
        names = cloud.names
        label_name = _label_name(names)
        if label_name in names:
            raise DataError(f"{self.out}: the input already has fields 'label' and 'prc_label'")
        step_in = cloud.point_step
        size = self.label_dtype.itemsize
        step_out = step_in + size
        kept = cloud.raw[keep]
        n = len(kept)
        out = np.empty((n, step_out), dtype=np.uint8)
        out[:, :step_in] = kept
        order = ">" if cloud.is_bigendian else "<"
        lab = np.asarray(labels)[keep]
        if lab.size and (lab.min() < 0 or lab.max() > np.iinfo(self.label_dtype).max):
            raise DataError(f"{self.out}: label codes outside {self.label_dtype}")
        out[:, step_in:] = lab.astype(self.label_dtype.newbyteorder(order)).view(np.uint8).reshape(n, size)
        dense = True
        if n:
            pts = kept.reshape(-1).view(cloud.points.dtype)
            dense = bool(all(np.isfinite(pts[c]).all() for c in "xyz"))
        fields = [*cloud.fields, Field(label_name, step_in, self._label_code, 1)]
        return self._ros_message(cloud, fields, out, 1, n, step_out, dense)

    def _ros_message(
        self,
        cloud: CloudMessage,
        fields: list[Field],
        raw: np.ndarray,
        height: int,
        width: int,
        point_step: int,
        dense: bool,
    ) -> Any:
        T = self._types
        stamp = T["builtin_interfaces/msg/Time"](sec=cloud.stamp_sec, nanosec=cloud.stamp_nanosec)
        if self.kind == "ros1":
            header = T["std_msgs/msg/Header"](seq=cloud.seq, stamp=stamp, frame_id=cloud.frame_id)
        else:
            header = T["std_msgs/msg/Header"](stamp=stamp, frame_id=cloud.frame_id)
        return T["sensor_msgs/msg/PointCloud2"](
            header=header,
            height=height,
            width=width,
            fields=[
                T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                for f in fields
            ],
            is_bigendian=cloud.is_bigendian,
            point_step=point_step,
            row_step=point_step * width,
            data=np.ascontiguousarray(raw).reshape(-1),
            is_dense=dense,
        )

    def _serialize_write(self, msg: Any, log_time_ns: int) -> None:
        if self.kind == "ros1":
            data = self._typestore.serialize_ros1(msg, POINTCLOUD2)
        else:
            data = self._typestore.serialize_cdr(msg, POINTCLOUD2)
        self._writer.write(self._conn, int(log_time_ns), data)

    def write_cloud(self, cloud: CloudMessage, log_time_ns: int | None = None) -> None:
        """Write a cloud unchanged (its own layout, height and width; no label added)."""
        if log_time_ns is None:
            log_time_ns = cloud.stamp_sec * 10**9 + cloud.stamp_nanosec
        msg = self._ros_message(
            cloud, list(cloud.fields), cloud.raw, cloud.height, cloud.width, cloud.point_step, cloud.is_dense
        )
        self._serialize_write(msg, log_time_ns)
        self.frames += 1
        self.points += cloud.height * cloud.width

    def write(self, scan: Scan, keep: np.ndarray, labels: np.ndarray) -> None:
        cloud = scan.meta.get("ros")
        if not isinstance(cloud, CloudMessage):
            raise DataError(
                f"{scan.source}: output format {self.kind} needs a ROS recording as input (--out-format pcd or kitti)"
            )
        keep, labels = self._check(scan, keep, labels, cloud.height * cloud.width)
        msg = self.message(cloud, keep, labels)
        log_time = int(scan.meta.get("log_time_ns", cloud.stamp_sec * 10**9 + cloud.stamp_nanosec))
        self._serialize_write(msg, log_time)
        self.frames += 1
        self.points += int(keep.sum())

    def close(self) -> None:
        if not getattr(self, "_open", False):
            return
        self._open = False
        self._writer.close()
        if self._tmp is not None:
            inner = self._tmp / f"{self._tmp.name}.mcap"
            inner.replace(self.out)
            shutil.rmtree(self._tmp)


# --------------------------------------------------------------------------------------------
# PCD folder, KITTI bins


def _frame_time(scan: Scan) -> float:
    t = scan.meta.get("frame_time")
    if t is not None:
        return float(t)
    pt = scan.point_times()
    return float(np.min(pt)) if pt is not None and len(pt) else 0.0


def _kept_columns(scan: Scan, keep: np.ndarray, labels: np.ndarray) -> dict[str, np.ndarray]:
    """x y z [intensity] [time] label of the kept points (input order)."""
    pts = np.asarray(scan.points(), dtype=np.float32)
    if len(pts) != len(keep):
        raise DataError(f"{scan.source}: {len(pts)} points for {len(keep)} keep flags")
    cols: dict[str, np.ndarray] = {"x": pts[keep, 0], "y": pts[keep, 1], "z": pts[keep, 2]}
    inten = None
    if scan.intensity is not None:
        inten = scan.per_point(scan.intensity)
    if inten is not None and len(inten) == len(keep):
        cols["intensity"] = np.asarray(inten, dtype=np.float32)[keep]
    times = scan.point_times()
    if times is not None and len(times) == len(keep):
        cols["time"] = (np.asarray(times, dtype=np.float64) - _frame_time(scan))[keep]
    cols["label"] = np.asarray(labels, dtype=np.uint16)[keep]
    return cols


def _label_name(names: Sequence[str]) -> str:
    return "label" if "label" not in names else "prc_label"


class PcdFolderWriter(StreamWriter):
    """``OUT/NNNNNN.pcd`` per frame (binary, unorganised) and ``OUT/times.txt`` (frame times, s).

    The kept points keep the input's own fields when the input has them (a recording's
    PointCloud2 fields, or a PCD/PLY folder's fields through ``source_fields``), plus
    ``label``; otherwise ``x y z [intensity] [time] label`` (``time`` in s from the frame time).

    Parameters
    ----------
    source_fields : callable(i) -> {name: (N,) array}, optional
        The raw fields of input sweep ``i`` (e.g. ``SweepFolder.fields``).
    label_dtype : ``uint8`` or ``uint16``
    """

    format = "pcd"

    def __init__(
        self,
        out: str | Path,
        *,
        source_fields: Callable[[int], dict[str, np.ndarray]] | None = None,
        label_dtype: str = "uint8",
        overwrite: bool = False,
    ) -> None:
        super().__init__(out)
        _check_new(self.out, overwrite)
        self.out.mkdir(parents=True)
        self._times: list[float] = []
        self._source_fields = source_fields
        self.label_dtype = np.dtype(label_dtype)

    def _input_fields(self, scan: Scan, n: int) -> dict[str, np.ndarray] | None:
        cloud = scan.meta.get("ros")
        if isinstance(cloud, CloudMessage):
            pts = cloud.points
            fields = {name: pts[name] for name in cloud.names}
        elif self._source_fields is not None:
            fields = dict(self._source_fields(self.frames))
        else:
            return None
        fields = {k: np.asarray(v) for k, v in fields.items() if k}
        if any(len(v) != n for v in fields.values()) or not all(c in fields for c in "xyz"):
            return None
        return {c: fields.pop(c) for c in "xyz"} | fields

    def write(self, scan: Scan, keep: np.ndarray, labels: np.ndarray) -> None:
        keep, labels = self._check(scan, keep, labels, len(keep))
        fields = self._input_fields(scan, len(keep))
        if fields is None:
            cols = _kept_columns(scan, keep, labels)
            cols["label"] = cols["label"].astype(self.label_dtype)
        else:
            cols = {k: v[keep] for k, v in fields.items()}
            cols[_label_name(list(cols))] = np.asarray(labels)[keep].astype(self.label_dtype)
        write_pcd(self.out / f"{scan.name}.pcd", cols)
        self._times.append(_frame_time(scan))
        self.frames += 1
        self.points += int(keep.sum())

    def close(self) -> None:
        if self._times:
            np.savetxt(self.out / "times.txt", np.asarray(self._times), fmt="%.9f")


class KittiBinWriter(StreamWriter):
    """KITTI layout: ``velodyne/*.bin``, ``labels/*.label``, ``times.txt``, ``poses.txt``, ``calib.txt``."""

    format = "kitti"

    def __init__(self, out: str | Path, *, poses: np.ndarray | None = None, overwrite: bool = False) -> None:
        super().__init__(out)
        _check_new(self.out, overwrite)
        (self.out / "velodyne").mkdir(parents=True)
        (self.out / "labels").mkdir()
        self.poses = poses
        self._times: list[float] = []

    def write(self, scan: Scan, keep: np.ndarray, labels: np.ndarray) -> None:
        keep, labels = self._check(scan, keep, labels, len(keep))
        cols = _kept_columns(scan, keep, labels)
        inten = cols.get("intensity", np.zeros(len(cols["x"]), np.float32))
        np.column_stack([cols["x"], cols["y"], cols["z"], inten]).astype(np.float32).tofile(
            self.out / "velodyne" / f"{scan.name}.bin"
        )
        L.to_label_file(cols["label"].astype(np.uint8)).tofile(self.out / "labels" / f"{scan.name}.label")
        self._times.append(_frame_time(scan))
        self.frames += 1
        self.points += int(keep.sum())

    def close(self) -> None:
        if not self._times:
            return
        t = np.asarray(self._times)
        np.savetxt(self.out / "times.txt", t - t[0], fmt="%.6e")
        if self.poses is not None and len(self.poses) == len(t):
            from data_tools.formats.trajectory_io import write_kitti_poses

            write_kitti_poses(self.out / "poses.txt", np.asarray(self.poses))
            (self.out / "calib.txt").write_text(
                "".join(f"P{i}: 1 0 0 0 0 1 0 0 0 0 1 0\n" for i in range(4)) + "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n"
            )


def default_out_format(dataset: Any) -> str:
    """The output kind matching the input: the recording's kind, ``pcd`` for PCD folders, else ``kitti``."""
    fmt = getattr(dataset, "format", "")
    if fmt == "rosbag":
        return getattr(dataset, "kind", "mcap")
    if fmt in ("pcd", "ply"):
        return "pcd"
    if fmt == "kitti":
        return "kitti"
    return "pcd"


def out_format_from_path(out: Path) -> str | None:
    """Output kind implied by the output path's suffix (``.bag``, ``.mcap``, ``.db3``), if any."""
    return bag_kind(out) if out.suffix.lower() in (".bag", ".mcap", ".db3") else None


def open_stream_writer(
    out: str | Path,
    dataset: Any,
    out_format: str | None = None,
    *,
    label_dtype: str = "uint8",
    overwrite: bool = False,
) -> StreamWriter:
    """A writer for the filtered stream of ``dataset``.

    ``out_format`` (``mcap``, ``ros2``, ``ros1``, ``pcd``, ``kitti``) defaults to the suffix of
    ``out`` (``.mcap``, ``.bag``) or else to the input's own kind (:func:`default_out_format`).
    """
    out = Path(out)
    fmt = out_format or out_format_from_path(out) or default_out_format(dataset)
    if fmt not in OUT_FORMATS:
        raise DataError(f"{out}: unknown output format {fmt!r}; choose from {', '.join(OUT_FORMATS)}")
    if fmt in ("ros1", "ros2", "mcap"):
        if getattr(dataset, "format", "") != "rosbag":
            raise DataError(
                f"{out}: output format {fmt} needs a ROS 1/2 or MCAP input (this input is "
                f"{getattr(dataset, 'format', '?')}); use --out-format pcd or kitti"
            )
        storage = "mcap" if getattr(dataset, "storage", "") == "mcap" else "sqlite3"
        return RosCloudWriter(out, fmt, dataset.topic, storage=storage, label_dtype=label_dtype, overwrite=overwrite)
    if fmt == "pcd":
        fields = getattr(dataset, "fields", None)
        return PcdFolderWriter(
            out, source_fields=fields if callable(fields) else None, label_dtype=label_dtype, overwrite=overwrite
        )
    return KittiBinWriter(out, poses=getattr(dataset, "poses", None), overwrite=overwrite)
