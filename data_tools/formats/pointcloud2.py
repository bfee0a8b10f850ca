"""``sensor_msgs/PointCloud2`` messages: decoded, their per-point times in seconds, organised into Scans.

Decoding honours ``point_step``, ``row_step``, every field's offset, datatype and count, and
``is_bigendian``: the message data is viewed through a numpy structured dtype built from the
fields, without per-point loops.

Organising (``data_tools.organize``):

- an organised cloud (``height > 1``, e.g. the Ouster ROS driver: ``height`` = beams) goes to
  :meth:`Organizer.scan_organized` as the ``(height, width, 3)`` grid, unless its ring field
  varies along a row (rows are then not beams, e.g. one firing per row: its points are
  organised as an unorganised cloud);
- an unorganised cloud (``height == 1``, e.g. the Velodyne ROS driver: x y z intensity ring
  time) goes to :meth:`Organizer.scan` with its ring field (``ring``, ``channel``,
  ``laser_id``, ...) when it has one.

Per-point time fields (first present of :data:`TIME_FIELDS`) are converted to absolute
seconds. The unit is detected once per sequence (see :func:`time_unit`): the field's span
over one sweep is compared with the sweep period measured from the header stamps (median
spacing), and the unit among s, ms, us, ns that makes the span closest to the period is
taken; with a single message the datatype decides (floating point: s, integer: ns). Values
above 1e6 s are absolute (epoch) times; others are relative to the header stamp (Ouster
``t`` counts ns from the stamp, the Velodyne driver's ``time`` may be negative when the stamp
is the end of the sweep). The header stamp is the frame time; when every header stamp of the
topic is the same (unset by the driver), the recording's log times are, with a warning.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from data_tools.errors import DataError
from prc_slam.scan import Scan

log = logging.getLogger("prc_slam.rosbag")  # (the messages of a recording, under one name)

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
#: PointField datatype codes -> numpy type (without byte order).
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
DATATYPE_CODES = {v: k for k, v in DATATYPES.items()}
#: Per-point time fields, in order of preference.
TIME_FIELDS = ("t", "time", "timestamp", "timestamps", "time_stamp", "offset_time", "time_offset", "stamps")
#: Ring / channel fields, in order of preference (not Livox's ``line``: the laser of a
#: non-repetitive pattern, whose points of one laser do not form a scan line).
RING_FIELDS = ("ring", "channel", "laser_id", "ring_id", "laser_number")
#: Intensity fields, in order of preference.
INTENSITY_FIELDS = ("intensity", "reflectivity", "remission", "i", "signal")
#: Candidate time units (seconds per count), coarsest first.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: Values above this (s) are absolute epoch times, below it offsets from the header stamp.
ABSOLUTE_TIME_S = 1e6
#: Point times further than this (s) from the header stamp at both ends of a sweep are on another clock.
CLOCK_MISMATCH_S = 1.0


@dataclass(frozen=True)
class Field:
    """One ``sensor_msgs/PointField``."""

    name: str
    offset: int
    datatype: int
    count: int = 1


@dataclass
class CloudMessage:
    """One decoded ``PointCloud2``: the raw point bytes and everything needed to write it back.

    Attributes
    ----------
    raw : uint8 (height * width, point_step)
        Each point's bytes, row-major (row padding beyond ``width * point_step`` removed).
    points : structured ndarray (height * width,)
        ``raw`` viewed through the fields' dtype.
    """

    raw: np.ndarray
    points: np.ndarray
    fields: tuple[Field, ...]
    height: int
    width: int
    point_step: int
    is_bigendian: bool
    is_dense: bool
    frame_id: str
    stamp_sec: int
    stamp_nanosec: int
    seq: int = 0

    @property
    def stamp(self) -> float:
        """Header stamp (s)."""
        return self.stamp_sec + self.stamp_nanosec * 1e-9

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)


def cloud_from_records(
    records: np.ndarray,
    *,
    height: int = 1,
    frame_id: str = "lidar",
    stamp_ns: int = 0,
    seq: int = 0,
    is_dense: bool | None = None,
) -> CloudMessage:
    """A :class:`CloudMessage` from a structured array (fields, offsets, byte order and
    ``itemsize`` of its dtype become the PointFields, ``is_bigendian`` and ``point_step``).

    ``records`` holds ``height * width`` points row-major; every field must have one byte
    order (the message has one ``is_bigendian`` flag).
    """
    records = np.ascontiguousarray(records).reshape(-1)
    dt = records.dtype
    if dt.names is None:
        raise DataError("cloud_from_records: a structured array is needed")
    fields, orders = [], set()
    for name in dt.names:
        sub, offset = dt.fields[name][:2]
        base, count = (sub.base, int(np.prod(sub.shape))) if sub.shape else (sub, 1)
        code = DATATYPE_CODES.get(base.str[1:])
        if code is None:
            raise DataError(f"cloud_from_records: field {name!r} has no PointField datatype ({base})")
        if base.itemsize > 1:
            orders.add(base.str[0])
        fields.append(Field(name, int(offset), code, count))
    if len(orders) > 1:
        raise DataError("cloud_from_records: fields mix byte orders")
    big = orders == {">"}
    n = len(records)
    if height < 1 or n % height:
        raise DataError(f"cloud_from_records: {n} points do not fill {height} rows")
    raw = records.view(np.uint8).reshape(n, dt.itemsize)
    if is_dense is None:
        is_dense = bool(all(np.isfinite(records[c]).all() for c in "xyz" if c in dt.names))
    sec, nsec = divmod(int(stamp_ns), 10**9)
    return CloudMessage(
        raw=raw,
        points=records,
        fields=tuple(fields),
        height=int(height),
        width=n // height,
        point_step=dt.itemsize,
        is_bigendian=big,
        is_dense=is_dense,
        frame_id=frame_id,
        stamp_sec=sec,
        stamp_nanosec=nsec,
        seq=seq,
    )


def fields_dtype(fields: Sequence[Field], point_step: int, is_bigendian: bool, source: str) -> np.dtype:
    """Numpy structured dtype of one point (``itemsize == point_step``, offsets as given).

    Raises
    ------
    DataError
        Unknown datatype, duplicate names, or a field reaching beyond ``point_step``.
    """
    order = ">" if is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in fields:
        if f.datatype not in DATATYPES:
            raise DataError(f"{source}: field {f.name!r} has unknown PointField datatype {f.datatype}")
        if f.name in names:
            raise DataError(f"{source}: field {f.name!r} appears twice")
        base = np.dtype(order + DATATYPES[f.datatype])
        count = max(int(f.count), 1)
        fmt = base if count == 1 else np.dtype((base, (count,)))
        if f.offset < 0 or f.offset + fmt.itemsize > point_step:
            raise DataError(
                f"{source}: field {f.name!r} (offset {f.offset}, {fmt.itemsize} bytes) lies outside "
                f"point_step {point_step}"
            )
        names.append(f.name)
        formats.append(fmt)
        offsets.append(int(f.offset))
    try:
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": int(point_step)})
    except ValueError as exc:  # overlapping fields
        raise DataError(f"{source}: fields do not form a valid point layout: {exc}") from exc


def decode_cloud(msg: Any, source: str) -> CloudMessage:
    """Decode a deserialised ``PointCloud2`` (any rosbags typestore) into a :class:`CloudMessage`.

    Raises
    ------
    DataError
        Inconsistent sizes, unknown datatypes, or no ``x``, ``y``, ``z`` fields.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    fields = tuple(Field(str(f.name), int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields)
    missing = [c for c in "xyz" if c not in {f.name for f in fields}]
    if missing:
        raise DataError(
            f"{source}: PointCloud2 has no {', '.join(missing)} field "
            f"(fields: {', '.join(f.name for f in fields) or 'none'})"
        )
    if point_step <= 0 and height * width > 0:
        raise DataError(f"{source}: point_step is {point_step}")
    if row_step < width * point_step:
        raise DataError(f"{source}: row_step {row_step} < width {width} x point_step {point_step}")
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if data.size != height * row_step:
        raise DataError(
            f"{source}: data holds {data.size} bytes, height {height} x row_step {row_step} = {height * row_step}"
        )
    big = bool(msg.is_bigendian)
    dtype = fields_dtype(fields, max(point_step, 1), big, source)
    if height * width == 0:
        raw = np.zeros((0, max(point_step, 1)), np.uint8)
    else:
        raw = data.reshape(height, row_step)[:, : width * point_step].reshape(height * width, point_step)
        raw = np.ascontiguousarray(raw)
    points = raw.reshape(-1).view(dtype)
    header = msg.header
    return CloudMessage(
        raw=raw,
        points=points,
        fields=fields,
        height=height,
        width=width,
        point_step=point_step,
        is_bigendian=big,
        is_dense=bool(msg.is_dense),
        frame_id=str(header.frame_id),
        stamp_sec=int(header.stamp.sec),
        stamp_nanosec=int(header.stamp.nanosec),
        seq=int(getattr(header, "seq", 0)),
    )


def _first(names: Sequence[str], candidates: Sequence[str]) -> str | None:
    lower = {n.lower(): n for n in names}
    for c in candidates:
        if c in lower:
            return lower[c]
    return None


def _column(points: np.ndarray, name: str) -> np.ndarray:
    """One field as a 1-D native-endian array (first element of a multi-count field)."""
    v = points[name]
    if v.ndim > 1:
        v = v[:, 0]
    return v.astype(v.dtype.newbyteorder("="), copy=False)


def time_unit(values: np.ndarray, period: float | None) -> tuple[str, float]:
    """Detect the unit of a per-point time field.

    Parameters
    ----------
    values : (N,) raw field values of one sweep
    period : float or None
        Sweep period (s), e.g. the median spacing of the header stamps; None when unknown.

    Returns
    -------
    name, seconds_per_count : the unit (``s``, ``ms``, ``us``, ``ns``) and its scale.
        Without a usable period (or a zero span): seconds for floating-point fields,
        nanoseconds for integer ones.
    """
    v = np.asarray(values)
    default = "s" if v.dtype.kind == "f" else "ns"
    finite = v[np.isfinite(v)] if v.dtype.kind == "f" else v
    if finite.size < 2 or period is None or not np.isfinite(period) or period <= 0:
        return default, TIME_UNITS[default]
    span = float(finite.max()) - float(finite.min())
    if span <= 0:
        return default, TIME_UNITS[default]
    best = min(TIME_UNITS, key=lambda u: abs(np.log(span * TIME_UNITS[u] / period)))
    return best, TIME_UNITS[best]


@dataclass
class TimeField:
    """How a sequence's per-point time field becomes seconds (decided once per sequence)."""

    name: str
    unit: str
    scale: float
    absolute: bool
    #: sweeps whose point times were on another clock than the header stamps (warned once)
    rebased: int = 0

    def describe(self) -> str:
        return f"{self.name} [{self.unit}, {'absolute' if self.absolute else 'relative to the header stamp'}]"

    def seconds(self, cloud: CloudMessage, source: str = "") -> np.ndarray:
        """Absolute time (s) of every point, ``float64 (N,)``.

        Point times more than :data:`CLOCK_MISMATCH_S` from the header stamp at both ends of the
        sweep are on another clock (a sensor's own epoch or uptime beside ROS time): their
        offsets within the sweep are kept and the sweep is put to start at the header stamp,
        with one warning per sequence (frame and point times must share one clock)."""
        raw = _column(cloud.points, self.name)
        if raw.dtype.kind in "iu" and raw.size:  # offset from the smallest value first: exact in float64
            base = raw.min()
            v = (raw - base).astype(np.float64) * self.scale + float(base) * self.scale
        else:
            v = raw.astype(np.float64) * self.scale
        if not self.absolute:
            v = v + cloud.stamp
        finite = v[np.isfinite(v)]
        if finite.size:
            lo, hi = float(finite.min()), float(finite.max())
            if min(abs(lo - cloud.stamp), abs(hi - cloud.stamp)) > CLOCK_MISMATCH_S:
                if not self.rebased:
                    log.warning(
                        "%s: per-point times (%s) start at %.6f s, %.1f s from the header stamp %.6f s: another "
                        "clock; each sweep's point times are shifted to start at its header stamp",
                        source or "cloud",
                        self.describe(),
                        lo,
                        lo - cloud.stamp,
                        cloud.stamp,
                    )
                self.rebased += 1
                v = v - lo + cloud.stamp
        return v


def detect_time_field(cloud: CloudMessage, period: float | None) -> TimeField | None:
    """The per-point time field of ``cloud`` and its unit, or None when it has none or when it
    holds one value for every point (a driver that leaves it unset; logged)."""
    name = _first(cloud.names, TIME_FIELDS)
    if name is None:
        return None
    raw = _column(cloud.points, name)
    finite = raw[np.isfinite(raw)] if raw.dtype.kind == "f" else raw
    if finite.size == 0 or finite.min() == finite.max():
        log.info("per-point time field %r is constant in the first sweep; ignored", name)
        return None
    unit, scale = time_unit(raw, period)
    absolute = bool(finite.size) and float(np.abs(finite.astype(np.float64)).max()) * scale > ABSOLUTE_TIME_S
    return TimeField(name, unit, scale, absolute)


def cloud_xyz(cloud: CloudMessage) -> np.ndarray:
    """``(N, 3)`` coordinates in input order (non-finite values kept: no returns); float32 when
    the three fields are float32, else float64."""
    pts = cloud.points
    single = all(pts.dtype.fields[c][0].base.str[1:] == "f4" for c in "xyz")
    out = np.empty((len(pts), 3), dtype=np.float32 if single else np.float64)
    for k, c in enumerate("xyz"):
        out[:, k] = _column(pts, c)
    return out


def cloud_to_scan(
    cloud: CloudMessage,
    organizer: Any,
    *,
    name: str,
    source: str,
    time_field: TimeField | None = None,
    row_lines: dict[tuple[int, int], bool] | None = None,
) -> Scan:
    """Organise one decoded cloud into a :class:`Scan` (see the module docstring).

    ``row_lines`` caches, per ``(height, width)``, whether an organised cloud's rows are scan
    lines (:func:`data_tools.formats.pcd.rows_are_scan_lines`; a sequence passes one dict for all its
    clouds, so that the check runs once per grid shape).

    The Scan's ``meta["ros"]`` keeps the decoded message (raw bytes, fields, header) so that
    a writer can emit the same points with a label field added.
    """
    xyz = cloud_xyz(cloud)
    names = cloud.names
    times = time_field.seconds(cloud, source) if time_field is not None else None
    inten_name = _first(names, INTENSITY_FIELDS)
    intensity = _column(cloud.points, inten_name).astype(np.float32) if inten_name else None
    frame_time = cloud.stamp
    ring_name = _first(names, RING_FIELDS)
    ring = _column(cloud.points, ring_name).astype(np.int64) if ring_name else None
    organised = cloud.height > 1
    if organised and ring is not None:
        grid = ring.reshape(cloud.height, cloud.width)
        if not (grid == grid[:, :1]).all():  # rows are not rings (e.g. one firing per row): organise the points
            organised = False
            log.info("%s: organised cloud whose rows are not rings; organised from its %s field", source, ring_name)
    if organised and ring is None:  # one firing per row (height = columns, width = beams)?
        from data_tools.formats.pcd import rows_are_scan_lines

        key = (cloud.height, cloud.width)
        lines = row_lines.get(key) if row_lines is not None else None
        if lines is None:
            lines = rows_are_scan_lines(xyz.reshape(cloud.height, cloud.width, 3))
            if not lines:
                log.warning(
                    "%s: organised cloud of %d x %d whose rows are not scan lines (its directions cover less "
                    "along a row than down a column: one firing per row?): organised from its points",
                    source,
                    cloud.height,
                    cloud.width,
                )
            if row_lines is not None:
                row_lines[key] = lines
        organised = lines
    if organised:
        h, w = cloud.height, cloud.width
        scan = organizer.scan_organized(
            xyz.reshape(h, w, 3),
            times=None if times is None else times.reshape(h, w),
            intensity=None if intensity is None else intensity.reshape(h, w),
            name=name,
            source=source,
            frame_time=frame_time,
        )
    else:
        scan = organizer.scan(
            xyz,
            ring=ring,
            times=times,
            intensity=intensity,
            name=name,
            source=source,
            frame_time=frame_time,
        )
    scan.meta["ros"] = cloud
    scan.meta["frame_time"] = frame_time
    if time_field is not None:
        scan.meta["time_field"] = time_field.describe()
    return scan
