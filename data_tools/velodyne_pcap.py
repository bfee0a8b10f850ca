"""Velodyne packet captures (``.pcap``) decoded with ``velodyne-decoder`` and organised into Scans.

The decoder (C++, the ROS driver's decoding) turns the 1206-byte UDP data packets into sweeps of
points with ``x y z intensity time column ring return_type``; every sweep then goes through the
one organiser (:class:`data_tools.organize.Organizer`) with its ``ring`` field and per-point times,
so labels come back one per decoded point, in decoding order. The sensor model is read from the
packets' factory byte (VLP-16, VLP-32C, HDL-32E, Puck Hi-Res, VLS-128, Alpha Prime); HDL-64E
captures carry their calibration in the stream, which the decoder reads itself.

Frame ``i`` is the ``i``-th sweep the decoder emits; an index of sweep stamps is built once when
the capture is opened. Reading in order streams the file once; going back reopens it.
"""

from __future__ import annotations

import dataclasses
import logging
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from data_tools.errors import DataError
from data_tools.sequence import SequenceBase
from prc_slam.scan import Scan

log = logging.getLogger("prc_slam.readers")

DATA_PACKET_SIZE = 1206
# factory byte (last byte of a data packet) -> velodyne_decoder.Model name, number of lasers
FACTORY_MODELS = {
    0x21: ("HDL32E", 32),
    0x22: ("VLP16", 16),
    0x24: ("PuckHiRes", 16),
    0x28: ("VLP32C", 32),
    0xA1: ("VLS128", 128),
}
MODEL_LASERS = {
    "HDL64E_S1": 64,
    "HDL64E_S2": 64,
    "HDL64E_S3": 64,
    "HDL32E": 32,
    "VLP32A": 32,
    "VLP32B": 32,
    "VLP32C": 32,
    "VLP16": 16,
    "PuckLite": 16,
    "PuckHiRes": 16,
    "VLS128": 128,
    "AlphaPrime": 128,
}


def udp_payloads(path: str | Path, limit: int = 64) -> list[bytes]:
    """The first ``limit`` UDP payloads of a classic libpcap capture (Ethernet, Linux SLL or raw IP
    link layers, IPv4, optional VLAN tags). Returns [] for anything else (e.g. pcapng)."""
    out: list[bytes] = []
    try:
        with Path(path).open("rb") as f:
            head = f.read(24)
            if len(head) < 24:
                return out
            magic = head[:4]
            if magic in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1"):
                endian = "<"
            elif magic in (b"\xa1\xb2\xc3\xd4", b"\xa1\xb2\x3c\x4d"):
                endian = ">"
            else:
                return out
            link = struct.unpack(endian + "I", head[20:24])[0] & 0x0FFFFFFF
            while len(out) < limit:
                rec = f.read(16)
                if len(rec) < 16:
                    break
                incl = struct.unpack(endian + "IIII", rec)[2]
                frame = f.read(incl)
                if len(frame) < incl:
                    break
                payload = _udp_payload(frame, link)
                if payload is not None:
                    out.append(payload)
    except OSError:
        return out
    return out


def _udp_payload(frame: bytes, link: int) -> bytes | None:
    if link == 1:  # Ethernet
        off, ethertype = 14, frame[12:14]
        while ethertype in (b"\x81\x00", b"\x88\xa8") and len(frame) >= off + 4:  # VLAN tags
            ethertype, off = frame[off + 2 : off + 4], off + 4
    elif link == 113:  # Linux cooked capture
        off, ethertype = 16, frame[14:16]
    elif link in (101, 12, 228):  # raw IPv4
        off, ethertype = 0, b"\x08\x00"
    else:
        return None
    if ethertype != b"\x08\x00" or len(frame) < off + 20:
        return None
    ihl = (frame[off] & 0x0F) * 4
    if frame[off + 9] != 17:  # not UDP
        return None
    udp = off + ihl
    return frame[udp + 8 :]


def looks_like_velodyne(path: str | Path) -> bool:
    """True when the capture's first UDP packets include Velodyne data packets (1206 bytes,
    first block flag 0xFFEE)."""
    return any(len(p) == DATA_PACKET_SIZE and p[:2] == b"\xff\xee" for p in udp_payloads(path))


def detect_model(path: str | Path) -> str | None:
    """The sensor model from the factory byte of the first data packet (None for the HDL-64E,
    whose packets carry no factory byte; the decoder detects it and its calibration itself)."""
    for p in udp_payloads(path):
        if len(p) == DATA_PACKET_SIZE and p[:2] == b"\xff\xee":
            entry = FACTORY_MODELS.get(p[-1])
            return None if entry is None else entry[0]
    return None


class VelodynePcapSequence(SequenceBase):
    """The sweeps of one Velodyne ``.pcap`` as Scans (Dataset protocol), organised by the ring field.

    Parameters
    ----------
    path : the ``.pcap``
    model : velodyne_decoder model name (``VLP16``, ``VLP32C``, ``HDL32E``, ``HDL64E_S3``, ...);
        default: from the packets' factory byte
    calibration : optional calibration ``.yml`` (velodyne_decoder / ROS driver format)

    Attributes
    ----------
    times : float64 (n,)
        Stamp (s) of each sweep (the sensor's clock when available, else the capture's).
    """

    format = "velodyne-pcap"

    def __init__(self, path: str | Path, *, model: str | None = None, calibration: str | Path | None = None) -> None:
        path = Path(path)
        if not path.is_file():
            raise DataError(f"{path}: no such file")
        try:
            import velodyne_decoder as vd
        except ImportError as exc:
            msg = "reading Velodyne pcaps needs velodyne-decoder (pip install velodyne-decoder)"
            raise DataError(f"{path}: {msg}") from exc
        self._vd = vd
        self.root = path
        self.name = path.stem
        self.poses = None
        model = model or detect_model(path)
        if model is not None and model not in vd.Model.__members__:
            raise DataError(f"{path}: unknown Velodyne model {model!r}; choose from {list(vd.Model.__members__)}")
        self.model = model
        self.calibration = None
        if calibration is not None:
            try:
                self.calibration = vd.Calibration.read(str(calibration))
            except (RuntimeError, ValueError, OSError) as exc:
                raise DataError(f"{path}: cannot read Velodyne calibration {calibration}: {exc}") from exc
        self.rows = MODEL_LASERS.get(model) if model else None
        from data_tools.organize import Organizer

        self.organizer = Organizer(rows=self.rows, source_name=str(path))
        stamps = [t for t, _ in self._sweeps()]
        if not stamps:
            raise DataError(f"{path}: no Velodyne sweeps decoded (no 1206-byte data packets?)")
        self._n = len(stamps)
        t = np.asarray(stamps, dtype=np.float64)
        self.times = t if (np.diff(t) > 0).all() else None
        self.files = [path] * self._n
        self._stream: Iterator | None = None
        self._pos = 0

    def _config(self):
        vd = self._vd
        config = vd.Config()
        if self.model is not None:
            config.model = getattr(vd.Model, self.model)
        if self.calibration is not None:
            config.calibration = self.calibration
        return config

    def _sweeps(self) -> Iterator[tuple[float, np.ndarray]]:
        """(stamp in s, structured points) for every sweep of the capture, in order."""
        try:
            for stamp, points in self._vd.read_pcap(str(self.root), self._config(), as_pcl_structs=True):
                s = getattr(stamp, "device", None)
                s = float(stamp.host if not s else s) if hasattr(stamp, "host") else float(stamp)
                yield s, points
        except (ValueError, RuntimeError, OSError) as exc:
            msg = " ".join(str(exc).split()) or type(exc).__name__
            raise DataError(f"{self.root}: cannot decode Velodyne pcap: {msg}") from exc
        except Exception as exc:  # dpkt raises its own errors on truncated captures
            if type(exc).__module__.startswith("dpkt"):
                raise DataError(f"{self.root}: cannot read pcap (truncated?): {exc}") from exc
            raise

    def __len__(self) -> int:
        return self._n

    def sweep(self, i: int) -> tuple[float, np.ndarray]:
        """Sweep ``i`` as (stamp, structured points ``x y z intensity ring time``)."""
        if not -self._n <= i < self._n:
            raise IndexError(f"{self.root}: sweep {i} of {self._n}")
        i %= self._n
        if self._stream is None or self._pos > i:
            self._stream = self._sweeps()
            self._pos = 0
        while True:
            try:
                item = next(self._stream)
            except StopIteration as exc:
                raise DataError(f"{self.root}: capture changed while reading (sweep {i})") from exc
            self._pos += 1
            if self._pos - 1 == i:
                return item

    def __getitem__(self, i: int) -> Scan:
        i = int(i)
        stamp, pts = self.sweep(i)
        i %= self._n
        xyz = np.column_stack([pts["x"], pts["y"], pts["z"]]).astype(np.float32)
        times = stamp + np.asarray(pts["time"], dtype=np.float64)
        ring = np.asarray(pts["ring"]).astype(np.int64)
        intensity = np.asarray(pts["intensity"], dtype=np.float32)
        primary, partner = primary_returns(ring, np.asarray(pts["column"]), np.asarray(pts["return_type"]))
        src = f"{self.root}#sweep {i}"
        if primary.all():
            return self.organizer.scan(
                xyz, ring=ring, times=times, intensity=intensity, name=f"{i:06d}", source=src, frame_time=stamp
            )
        # dual return: the range image holds one return per firing (the strongest); the other
        # return of the same firing shares its slot, so it gets the same label back
        scan = self.organizer.scan(
            xyz[primary],
            ring=ring[primary],
            times=times[primary],
            intensity=intensity[primary],
            name=f"{i:06d}",
            source=src,
            frame_time=stamp,
        )
        pos = np.cumsum(primary) - 1  # index of each primary point in the organised subset
        slot = np.asarray(scan.point_slot)[pos[partner]]
        cloud = np.asarray(scan.cloud)
        full = np.empty((len(xyz), 3), dtype=cloud.dtype)
        full[primary] = cloud
        full[~primary] = xyz[~primary]
        meta = {**scan.meta, "second_returns": int((~primary).sum())}
        return dataclasses.replace(scan, cloud=full, point_slot=slot, meta=meta)


def primary_returns(ring: np.ndarray, column: np.ndarray, return_type: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One return per firing of each laser (dual-return modes emit two).

    Returns
    -------
    primary : bool (N,)
        The point kept in the range image for its (column, ring) firing: the first in decoding
        order that is not a ``LAST``-only return when there is one (the strongest, as in
        single-return mode).
    partner : int64 (N,)
        Index of the primary point of each point's firing (itself for a primary point).
    """
    n = len(ring)
    key = np.asarray(column, np.int64) * 4096 + np.asarray(ring, np.int64)
    last_only = np.asarray(return_type) == 2  # velodyne_decoder ReturnMode.LAST
    order = np.lexsort((np.arange(n), last_only, key))
    sk = key[order]
    first = np.ones(n, bool)
    first[1:] = sk[1:] != sk[:-1]
    group = np.cumsum(first) - 1
    head = order[first]
    partner = np.empty(n, np.int64)
    partner[order] = head[group]
    primary = partner == np.arange(n)
    return primary, partner
