"""Ouster packet captures (``.pcap`` + the sensor's ``.json`` metadata) read with ``ouster-sdk``.

This is the sensor's true raw stream: the SDK's low-level packet source and frame batcher turn
the UDP lidar packets (any packet profile the SDK knows: legacy, single/dual return, low
data rate ``RNG15_RFL8_NIR8``, ...) into organised ``LidarFrame`` images in measurement order
(staggered), with per-column timestamps and status. Of a dual-return profile the first (strongest)
return is read, with a warning (``field="RANGE2"`` reads the second). Each frame becomes the same Scan
:func:`data_tools.formats.ouster.ouster_scan` builds from a decoded ``.npz`` (ranges, reflectivity,
column times, beam intrinsics, ``pixel_shift_by_row``), with Cartesian coordinates from the
SDK's own lookup table (``XYZLut``) expressed in the *lidar* frame, as in ``xyz_lidar_m``.

Frame ``i`` of a capture is the ``i``-th run of consecutive lidar packets sharing one frame id
(an index built once when the capture is opened, without decoding). Reading frames in order
streams the file once; going back reopens it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from data_tools.errors import DataError
from data_tools.formats.ouster import ouster_scan
from data_tools.formats.velodyne_pcap import PCAP_SUFFIXES, check_not_hesai
from data_tools.sequence import Dataset, Reader, SequenceBase
from prc_slam.scan import Scan

log = logging.getLogger("prc_slam.readers")


def find_metadata(pcap: str | Path, meta: str | Path | None = None) -> Path:
    """The sensor metadata json of ``pcap``: ``meta`` when given, else ``<stem>.json`` beside it,
    else the json beside it whose stem is the longest prefix of the pcap's stem (a capture named
    ``<sensor>_<suffix>.pcap`` next to ``<sensor>.json``)."""
    pcap = Path(pcap)
    if meta is not None:
        meta = Path(meta)
        if not meta.is_file():
            raise DataError(f"{pcap}: metadata file {meta} does not exist")
        return meta
    exact = pcap.with_suffix(".json")
    if exact.is_file():
        return exact
    prefixed = [j for j in pcap.parent.glob("*.json") if pcap.stem.startswith(j.stem)]
    if prefixed:
        return max(prefixed, key=lambda j: len(j.stem))
    raise DataError(
        f"{pcap}: no Velodyne data packets and no Ouster sensor metadata: expected {exact.name} beside it (or give "
        f"the json with --meta PATH); {udp_traffic(pcap)}"
    )


def load_sensor_info(path: Path, pcap: Path):
    """Parse the metadata json into an ``ouster.sdk.core.SensorInfo`` (DataError when invalid)."""
    from ouster.sdk import core

    try:
        return core.SensorInfo(path.read_text())
    except (RuntimeError, ValueError, OSError, UnicodeDecodeError) as exc:
        msg = " ".join(line.strip() for line in str(exc).splitlines() if line.strip()) or type(exc).__name__
        msg = msg if len(msg) <= 300 else msg[:297] + "..."
        raise DataError(f"{pcap}: cannot use sensor metadata {path}: {msg}") from exc


def udp_traffic(path: Path, limit: int = 4) -> str:
    """The capture's UDP traffic in a few words (the busiest destination ports, packet sizes), to
    tell a port or profile that does not match the metadata."""
    from data_tools.formats.velodyne_pcap import DETECT_BYTES, DETECT_PACKETS, Capture

    counts: dict[tuple[int, int], int] = {}
    try:
        for _t, src, payload in Capture(path, max_packets=DETECT_PACKETS, max_bytes=DETECT_BYTES):
            key = (int(src.rpartition(" ")[2]), len(payload))
            counts[key] = counts.get(key, 0) + 1
    except DataError as exc:
        return str(exc).removeprefix(f"{path}: ")
    if not counts:
        return "the capture holds no UDP/IPv4 packets"
    top = sorted(counts.items(), key=lambda kv: -kv[1])[:limit]
    return "its UDP packets: " + ", ".join(f"port {port}: {n} of {size} bytes" for (port, size), n in top)


class OusterPcapSequence(SequenceBase):
    """The sweeps of one Ouster ``.pcap`` capture as Scans (Dataset protocol).

    Parameters
    ----------
    path : the ``.pcap``
    meta : the sensor metadata json (default: found by :func:`find_metadata`)
    destaggered : shift rows by ``pixel_shift_by_row`` so that columns are azimuths (the default, as
        :func:`data_tools.formats.ouster.read_ouster_npz`); False: measurement order, the raw stream
    field : the range channel to read (``RANGE``; ``RANGE2`` for the second return of dual-return profiles)

    Attributes
    ----------
    times : float64 (n,)
        Sensor time (s) of the first column of each frame.
    frame_ids : int64 (n,)
        The sensor's frame id of each frame.
    """

    format = "ouster-pcap"

    def __init__(
        self,
        path: str | Path,
        *,
        meta: str | Path | None = None,
        destaggered: bool = True,
        field: str = "RANGE",
    ) -> None:
        path = Path(path)
        if not path.is_file():
            raise DataError(f"{path}: no such file")
        self.root = path
        self.name = path.stem
        self.destaggered = destaggered
        self.field = field
        check_not_hesai(path)  # (not "no Ouster metadata" or "no lidar packets matching")
        self.meta_path = find_metadata(path, meta)
        self.info = load_sensor_info(self.meta_path, path)
        from ouster.sdk import core

        self._core = core
        self._format = core.PacketFormat(self.info)
        fields = list(self._format.fields)
        if field not in fields:
            raise DataError(
                f"{path}: packet profile {self.info.format.udp_profile_lidar} has no {field} channel (has {fields})"
            )
        if field == "RANGE" and "RANGE2" in fields:
            log.warning(
                "%s: packet profile %s holds two returns per pixel; the range image takes the first (strongest) "
                "only, the second returns (RANGE2) are not read",
                path,
                self.info.format.udp_profile_lidar,
            )
        self.poses = None
        self._index()
        self._lut = core.XYZLut(self.info, use_extrinsics=False)
        # XYZLut gives the sensor frame; xyz_lidar_m and the beam model are in the lidar frame
        t = np.linalg.inv(np.asarray(self.info.lidar_to_sensor_transform, dtype=np.float64))
        self._to_lidar = (t[:3, :3], t[:3, 3] / 1000.0)
        self._stream: Iterator | None = None
        self._pos = 0  # ordinal of the next item of the open stream

    # -- index -------------------------------------------------------------------------------
    def _source(self):
        from ouster.sdk._bindings import pcap as _pcap

        try:
            return _pcap.PcapPacketSource(str(self.root), sensor_info=[self.info])
        except (RuntimeError, ValueError, OSError) as exc:
            raise DataError(f"{self.root}: cannot open pcap: {str(exc).splitlines()[0]}") from exc

    def _index(self) -> None:
        """One pass over the packets: runs of lidar packets sharing a frame id = frames."""
        core = self._core
        starts: list[int] = []
        ends: list[int] = []  # one past the ordinal of the frame's last lidar packet
        ids: list[int] = []
        t0: list[float] = []
        last = None
        ordinal = -1
        top = -1  # the largest measurement id of a valid column
        src = self._source()
        try:
            for ordinal, (_, p) in enumerate(src):
                if not isinstance(p, core.LidarPacket):
                    continue
                valid = (np.asarray(self._format.packet_header(core.ColHeader.STATUS, p.buf)) & 1) != 0
                if valid.any():
                    mid = np.asarray(self._format.packet_header(core.ColHeader.MEASUREMENT_ID, p.buf))
                    top = max(top, int(mid[valid].max()))
                fid = p.frame_id()
                if fid != last:
                    starts.append(ordinal)
                    ends.append(ordinal)
                    ids.append(fid)
                    ts = self._format.packet_header(core.ColHeader.TIMESTAMP, p.buf)
                    st = self._format.packet_header(core.ColHeader.STATUS, p.buf)
                    ok = (np.asarray(st) & 1) != 0
                    t0.append(float(np.asarray(ts)[ok].min()) * 1e-9 if ok.any() else np.nan)
                    last = fid
                ends[-1] = ordinal + 1
            size_errors, id_errors = src.size_error_count, src.id_error_count
        except RuntimeError as exc:
            raise DataError(f"{self.root}: cannot read pcap (truncated?): {str(exc).splitlines()[0]}") from exc
        finally:
            src.close()
        if not starts:
            extra = (
                f" ({size_errors} packets of the wrong size, {id_errors} from another sensor (init id / serial))"
                if size_errors or id_errors
                else ""
            )
            raise DataError(
                f"{self.root}: no lidar packets matching {self.meta_path.name} "
                f"(profile {self.info.format.udp_profile_lidar}, {self._format.lidar_packet_size} bytes per packet, "
                f"udp_port_lidar {self.info.config.udp_port_lidar}){extra}; {udp_traffic(self.root)}"
            )
        self._check_columns(top, len(starts))
        self.n_items = ordinal + 1
        self._starts = np.asarray(starts, dtype=np.int64)
        self._ends = np.asarray(ends, dtype=np.int64)
        self.frame_ids = np.asarray(ids, dtype=np.int64)
        t = np.asarray(t0)
        self.times = None if np.isnan(t).any() or (np.diff(t) <= 0).any() else t
        self.size_errors, self.id_errors = int(size_errors), int(id_errors)
        if size_errors or id_errors:
            log.warning(
                "%s: %d packets of the wrong size and %d of another sensor (init id / serial) skipped",
                self.root,
                size_errors,
                id_errors,
            )
        self.files = [self.root] * len(starts)

    def _in_window(self) -> np.ndarray:
        """bool (columns_per_frame,): the measurement ids inside the metadata's column window."""
        lo, hi = self.info.format.column_window
        inside = np.zeros(self.info.format.columns_per_frame, bool)
        if lo <= hi:
            inside[lo : hi + 1] = True
        else:  # the window wraps around measurement id 0
            inside[lo:] = True
            inside[: hi + 1] = True
        return inside

    def _check_columns(self, top: int, frames: int) -> None:
        """The capture's measurement ids against the metadata's lidar mode: packets of a wider mode
        (ids beyond ``columns_per_frame``) would lose their columns, those of a narrower one (every
        sweep of several ending at half the columns or less) would be placed at the wrong azimuths.

        Raises
        ------
        DataError
            Naming the largest measurement id found and the metadata's lidar mode.
        """
        cols = int(self.info.format.columns_per_frame)
        narrower = frames > 1 and 0 <= top < cols // 2 and self._in_window()[top + 1 :].any()
        if top >= cols or narrower:
            raise DataError(
                f"{self.root}: its lidar packets carry measurement ids 0..{top} (a {top + 1}-column sweep), "
                f"but {self.meta_path.name} says lidar_mode {self.info.config.lidar_mode} ({cols} columns): "
                "the metadata is not this capture's (give its own json with --meta)"
            )

    def __len__(self) -> int:
        return len(self._starts)

    # -- frames ------------------------------------------------------------------------------
    def _packets(self, i: int) -> Iterator:
        """The lidar packets of frame ``i`` (streams forward; reopens the file to go back).

        The source reuses its packet buffers: consume each packet before asking for the next."""
        start, end = int(self._starts[i]), int(self._ends[i])
        if self._stream is None or self._pos > start:
            self._src = self._source()
            self._stream = iter(self._src)
            self._pos = 0
        core = self._core
        try:
            while self._pos < end:
                _, p = next(self._stream)
                self._pos += 1
                if self._pos > start and isinstance(p, core.LidarPacket):
                    yield p
        except StopIteration as exc:
            raise DataError(f"{self.root}: capture changed while reading (frame {i})") from exc
        except RuntimeError as exc:
            raise DataError(f"{self.root}: cannot read frame {i}: {str(exc).splitlines()[0]}") from exc

    def frame(self, i: int):
        """Frame ``i`` as the SDK's ``LidarFrame`` (staggered, measurement order)."""
        if not -len(self) <= i < len(self):
            raise IndexError(f"{self.root}: frame {i} of {len(self)}")
        i %= len(self)
        core = self._core
        lf = core.LidarFrame(self.info)
        batcher = core.FrameBatcher(self.info)
        for p in self._packets(i):
            batcher.batch(p, lf)
        return lf

    def __getitem__(self, i: int) -> Scan:
        i = int(i)
        lf = self.frame(i)
        i %= len(self)
        src = f"{self.root}#frame {i} (id {int(self.frame_ids[i])})"
        rng = np.asarray(lf.field(self.field))
        valid = (np.asarray(lf.status) & 1) != 0
        missing = int((self._in_window() & ~valid).sum())
        if missing:
            log.warning("%s: %d of %d columns missing (dropped packets or partial sweep)", src, missing, lf.w)
        refl = "REFLECTIVITY2" if self.field == "RANGE2" else "REFLECTIVITY"
        xyz = np.asarray(self._lut(rng), dtype=np.float64)
        rot, off = self._to_lidar
        xyz = xyz @ rot.T + off
        xyz[rng == 0] = 0.0
        return ouster_scan(
            range_mm=rng,
            column_ts_ns=np.asarray(lf.timestamp),
            beam_altitude_deg=np.asarray(self.info.beam_altitude_angles, dtype=np.float64),
            beam_azimuth_deg=np.asarray(self.info.beam_azimuth_angles, dtype=np.float64),
            pixel_shift_by_row=np.asarray(self.info.format.pixel_shift_by_row, dtype=np.int64),
            column_valid=valid,
            reflectivity=np.asarray(lf.field(refl)) if lf.has_field(refl) else None,
            xyz_lidar_m=xyz.astype(np.float32),
            destaggered=self.destaggered,
            name=f"{i:06d}",
            source=src,
            meta={
                "frame_id": int(lf.frame_id),
                "missing_columns": missing,
                "packet_profile": str(self.info.format.udp_profile_lidar),
                "sensor": f"{self.info.prod_line} sn {self.info.sn}",
            },
        )


def _is_ouster_pcap(path: Path) -> bool:
    """A capture that is not a Velodyne one (asked first): an Ouster one, whose metadata json must be found."""
    if path.is_dir() or path.suffix.lower() not in PCAP_SUFFIXES:
        return False
    check_not_hesai(path)
    find_metadata(path)  # a pcap without its json: one-line error naming the file
    return True


def _open_ouster_pcap(path: Path, options: dict[str, Any]) -> Dataset:
    meta = options.get("meta")
    return OusterPcapSequence(
        path, meta=None if meta is None else str(meta), destaggered=bool(options.get("destaggered", True))
    )


READER = Reader("ouster-pcap", ("meta", "destaggered"), _is_ouster_pcap, _open_ouster_pcap)
