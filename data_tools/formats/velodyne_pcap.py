"""Velodyne packet captures (``.pcap``) decoded with ``velodyne-decoder`` and organised into Scans.

The decoder (C++, the ROS driver's decoding) turns the 1206-byte UDP data packets into sweeps of
points with ``x y z intensity time column ring return_type``; every sweep then goes through the
one organiser (:class:`data_tools.organize.Organizer`) with its ``ring`` field and per-point times,
so labels come back one per decoded point, in decoding order. The sensor model is read from the
packets' factory byte (VLP-16, VLP-32C, HDL-32E, Puck Hi-Res, VLS-128, Alpha Prime); HDL-64E
captures carry their calibration in the stream, which is read from the status bytes.

The capture is read by :class:`Capture` (classic pcap with micro- or nanosecond stamps in either
byte order, or pcapng): only Velodyne data packets of one sensor (the sender and destination
port of the first data packet) reach the decoder; position (GPS, port 8308) packets and other
traffic are skipped, data packets of a second sensor are an error naming both (their packets
would interleave into one sweep), and a file cut inside a record is read up to there, with a
warning. A capture of Hesai packets (``0xEEFF``) is an error saying so (:func:`check_not_hesai`).

Frame ``i`` is the ``i``-th sweep the decoder emits; an index of sweep stamps is built once when
the capture is opened. Reading in order streams the file once; going back reopens it.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import struct
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from data_tools.errors import DataError
from data_tools.sequence import Dataset, Reader, SequenceBase
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
#: Models whose packets carry another model's factory byte (the decoder accepts them for it).
SAME_PACKETS = {"PuckLite": "VLP16", "AlphaPrime": "VLS128"}
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


#: Detection reads at most this many packets / bytes from the start of a capture.
DETECT_PACKETS = 4000
DETECT_BYTES = 32 * 2**20
#: Another source with at least this many Velodyne data packets makes the capture ambiguous.
OTHER_SOURCE_PACKETS = 10
PCAP_MAGIC = {  # magic (as read little endian) -> byte order, seconds per fraction unit
    0xA1B2C3D4: ("<", 1e-6),
    0xA1B23C4D: ("<", 1e-9),
    0xD4C3B2A1: (">", 1e-6),
    0x4D3CB2A1: (">", 1e-9),
}
PCAPNG_SHB = 0x0A0D0D0A


class Capture:
    """The UDP/IPv4 packets of a packet capture: classic libpcap (micro- or nanosecond stamps,
    either byte order) or pcapng, with Ethernet (VLAN tags too), Linux cooked (v1, v2) or raw IPv4
    links.

    Iterating yields ``(stamp_s, source, payload)`` per UDP packet, ``source`` being
    ``"src-ip -> port dst-port"``. A file that ends inside a record stops the iteration and sets
    :attr:`truncated` (the packets before it are kept). Non-UDP frames are skipped.

    Raises
    ------
    DataError
        Not a pcap / pcapng file (on iteration).
    """

    def __init__(self, path: str | Path, *, max_packets: int | None = None, max_bytes: int | None = None) -> None:
        self.path = Path(path)
        self.max_packets = max_packets
        self.max_bytes = max_bytes
        self.truncated = False
        self.format = ""

    def __iter__(self) -> Iterator[tuple[float, str, bytes]]:
        self.truncated = False
        count = 0
        try:
            with self.path.open("rb") as f:
                for stamp, link, frame in self._frames(f):
                    hit = _udp(frame, link)
                    if hit is not None:
                        yield stamp, hit[0], hit[1]
                    count += 1
                    if self.max_packets is not None and count >= self.max_packets:
                        return
                    if self.max_bytes is not None and f.tell() >= self.max_bytes:
                        return
        except OSError as exc:
            raise DataError(f"{self.path}: cannot read capture: {exc}") from exc

    def _frames(self, f) -> Iterator[tuple[float, int, bytes]]:
        head = f.read(24)
        if len(head) < 4:
            raise DataError(f"{self.path}: not a pcap or pcapng capture (file too short)")
        magic = struct.unpack("<I", head[:4])[0]
        if magic == PCAPNG_SHB:
            self.format = "pcapng"
            f.seek(0)
            yield from self._pcapng(f)
            return
        if magic not in PCAP_MAGIC or len(head) < 24:
            raise DataError(f"{self.path}: not a pcap or pcapng capture (magic {head[:4].hex()})")
        self.format = "pcap"
        endian, unit = PCAP_MAGIC[magic]
        link = struct.unpack(endian + "I", head[20:24])[0] & 0x0FFFFFFF
        while True:
            rec = f.read(16)
            if not rec:
                return
            if len(rec) < 16:
                self.truncated = True
                return
            sec, frac, incl, _orig = struct.unpack(endian + "IIII", rec)
            frame = f.read(incl)
            if len(frame) < incl:
                self.truncated = True
                return
            yield sec + frac * unit, link, frame

    def _pcapng(self, f) -> Iterator[tuple[float, int, bytes]]:
        endian = "<"
        links: list[tuple[int, float]] = []  # per interface: link type, seconds per stamp unit
        last = 0.0
        while True:
            head = f.read(8)
            if not head:
                return
            if len(head) < 8:
                self.truncated = True
                return
            btype = struct.unpack(endian + "I", head[:4])[0]
            if btype == PCAPNG_SHB:  # a section: its byte-order magic decides the endianness
                bom = f.read(4)
                if len(bom) < 4:
                    self.truncated = True
                    return
                endian = "<" if struct.unpack("<I", bom)[0] == 0x1A2B3C4D else ">"
                length = struct.unpack(endian + "I", head[4:8])[0]
                body = f.read(length - 12)
                links = []
                if len(body) < length - 12:
                    self.truncated = True
                    return
                continue
            length = struct.unpack(endian + "I", head[4:8])[0]
            if length < 12 or length % 4:
                raise DataError(f"{self.path}: damaged pcapng block (length {length}) at byte {f.tell() - 8}")
            body = f.read(length - 8)
            if len(body) < length - 8:
                self.truncated = True
                return
            body = body[:-4]
            if btype == 1:  # interface description
                link = struct.unpack(endian + "H", body[:2])[0]
                links.append((link, _tsresol(body[8:], endian)))
            elif btype in (6, 2):  # enhanced / obsolete packet block
                if btype == 6:
                    iface, hi, lo, cap = struct.unpack(endian + "IIII", body[:16])
                else:
                    iface, _drops, hi, lo, cap = struct.unpack(endian + "HHIII", body[:16])
                data = body[20 : 20 + cap]
                if iface >= len(links):
                    continue
                link, unit = links[iface]
                last = ((hi << 32) | lo) * unit
                yield last, link, data
            elif btype == 3 and links:  # simple packet block: no stamp, first interface
                orig = struct.unpack(endian + "I", body[:4])[0]
                yield last, links[0][0], body[4 : 4 + orig]


def _tsresol(options: bytes, endian: str) -> float:
    """Seconds per stamp unit of a pcapng interface (option ``if_tsresol``, default microseconds)."""
    k = 0
    while k + 4 <= len(options):
        code, size = struct.unpack(endian + "HH", options[k : k + 4])
        if code == 0:
            break
        if code == 9 and size >= 1:
            v = options[k + 4]
            return 2.0 ** -(v & 0x7F) if v & 0x80 else 10.0**-v
        k += 4 + size + (-size % 4)
    return 1e-6


def _udp(frame: bytes, link: int) -> tuple[str, bytes] | None:
    """``("src-ip -> port dst-port", payload)`` of a UDP/IPv4 frame, else None."""
    if link == 1:  # Ethernet
        off, ethertype = 14, frame[12:14]
        while ethertype in (b"\x81\x00", b"\x88\xa8") and len(frame) >= off + 4:  # VLAN tags
            ethertype, off = frame[off + 2 : off + 4], off + 4
    elif link == 113:  # Linux cooked capture
        off, ethertype = 16, frame[14:16]
    elif link == 276:  # Linux cooked capture v2 (tcpdump -i any)
        off, ethertype = 20, frame[0:2]
    elif link in (101, 12, 228):  # raw IPv4
        off, ethertype = 0, b"\x08\x00"
    else:
        return None
    if ethertype != b"\x08\x00" or len(frame) < off + 20:
        return None
    ihl = (frame[off] & 0x0F) * 4
    if frame[off + 9] != 17 or len(frame) < off + ihl + 8:  # not UDP
        return None
    src = ".".join(str(b) for b in frame[off + 12 : off + 16])
    udp = off + ihl
    dst_port = int.from_bytes(frame[udp + 2 : udp + 4], "big")
    return f"{src} -> port {dst_port}", frame[udp + 8 :]


def is_data_packet(payload: bytes) -> bool:
    """A Velodyne data packet: 1206 bytes, first block flag 0xFFEE."""
    return len(payload) == DATA_PACKET_SIZE and payload[:2] == b"\xff\xee"


def udp_payloads(path: str | Path, limit: int = 64) -> list[bytes]:
    """The first ``limit`` Velodyne data packets among the first :data:`DETECT_PACKETS` packets
    (:data:`DETECT_BYTES`) of a capture (pcap or pcapng); [] when there are none or the file is
    not a capture."""
    out: list[bytes] = []
    try:
        for _t, _src, payload in Capture(path, max_packets=DETECT_PACKETS, max_bytes=DETECT_BYTES):
            if is_data_packet(payload):
                out.append(payload)
                if len(out) >= limit:
                    break
    except DataError:
        return out
    return out


def check_capture(path: str | Path) -> None:
    """Raise :class:`DataError` when ``path`` is not a pcap / pcapng capture (empty, or another file)."""
    path = Path(path)
    if path.is_file() and path.stat().st_size == 0:
        raise DataError(f"{path}: empty file (no packet capture)")
    for _ in Capture(path, max_packets=1):
        break


def looks_like_velodyne(path: str | Path) -> bool:
    """True when the capture's first packets include Velodyne data packets (1206 bytes, first
    block flag 0xFFEE), whatever other traffic comes before them."""
    return bool(udp_payloads(path, limit=1))


#: First bytes of a Hesai data packet (the pre-header of Pandar64/QT/XT/128/AT128, the first block's
#: flag of Pandar40P), where a Velodyne packet has ``0xFFEE``.
HESAI_MAGIC = b"\xee\xff"


def check_not_hesai(path: str | Path, packets: int = 16) -> None:
    """Raise :class:`DataError` when a capture holds Hesai data packets (``packets`` of them
    among its first UDP payloads of 500 bytes or more, before 4 x as many others), which no
    reader here decodes. Smaller packets (GPS, PTP) are passed over."""
    sizes: dict[int, int] = {}
    ports: set[str] = set()
    others = 0
    for _t, src, payload in Capture(path, max_packets=DETECT_PACKETS, max_bytes=DETECT_BYTES):
        if len(payload) < 500:
            continue
        if not payload.startswith(HESAI_MAGIC):
            others += 1
            if others >= 4 * packets:
                return
            continue
        sizes[len(payload)] = sizes.get(len(payload), 0) + 1
        ports.add(src.rpartition(" ")[2])
        if sum(sizes.values()) >= packets:
            size = max(sizes, key=sizes.__getitem__)
            raise DataError(
                f"{path}: Hesai lidar packets ({size} bytes starting 0xEEFF, port {', '.join(sorted(ports))}) are "
                "not read here; convert the capture to PointCloud2 (bag/MCAP) or PCD sweeps with the Hesai driver "
                "(HesaiLidar_ROS_2.0, nebula) and read those"
            )


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
        if not path.exists():
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
        self.source: str | None = None  # "ip -> port n" of the sensor read (the first data packet's)
        self._others: dict[str, int] = {}
        self.truncated = False
        first = next((payload for _t, payload in self._packets()), None)
        if first is None:
            raise DataError(f"{path}: no Velodyne data packets (1206-byte UDP payloads starting 0xFFEE) in the capture")
        entry = FACTORY_MODELS.get(first[-1])
        if model is None:
            model = None if entry is None else entry[0]
        if model is not None and model not in vd.Model.__members__:
            raise DataError(f"{path}: unknown Velodyne model {model!r}; choose from {list(vd.Model.__members__)}")
        if model is not None and entry is not None and SAME_PACKETS.get(model, model) != entry[0]:
            raise DataError(
                f"{path}: --model {model} does not match the capture, whose packets are of a {entry[0]} "
                f"(factory byte 0x{first[-1]:02x}); leave --model out"
            )
        self.model = model
        self.calibration = None
        if calibration is not None:
            try:
                self.calibration = vd.Calibration.read(str(calibration))
            except (RuntimeError, ValueError, OSError) as exc:
                raise DataError(f"{path}: cannot read Velodyne calibration {calibration}: {exc}") from exc
        elif model is None:
            self._hdl64e_calibration()
        self.rows = MODEL_LASERS.get(self.model) if self.model else None
        from data_tools.organize import Organizer

        self.organizer = Organizer(rows=self.rows, source_name=str(path))
        stamps = [t for t, _ in self._sweeps()]
        self._check_sources()
        if self.truncated:
            log.warning("%s: the capture ends inside a packet record (truncated?); read up to there", path)
        if not stamps:
            raise DataError(f"{path}: no Velodyne sweeps decoded from {self.source}")
        self._n = len(stamps)
        t = np.asarray(stamps, dtype=np.float64)
        self.times = t if (np.diff(t) > 0).all() else None
        self.files = [path] * self._n
        self._stream: Iterator | None = None
        self._pos = 0

    def _packets(self) -> Iterator[tuple[float, bytes]]:
        """(capture stamp, payload) of the data packets of the capture's sensor, in capture order:
        the source (sender IP and destination port) of the first data packet. Data packets of
        other sources are counted in ``_others``; position (GPS) packets and other traffic are
        skipped."""
        cap = Capture(self.root)
        others: dict[str, int] = {}
        for t, src, payload in cap:
            if not is_data_packet(payload):
                continue
            if self.source is None:
                self.source = src
            if src != self.source:
                others[src] = others.get(src, 0) + 1
                continue
            yield t, payload
        self._others = others
        self.truncated = cap.truncated

    def _check_sources(self) -> None:
        """Several sensors in one capture: an error naming them (their packets would interleave
        into one sweep); a few stray packets of another source are dropped with a warning."""
        many = {s: n for s, n in self._others.items() if n >= OTHER_SOURCE_PACKETS}
        if many:
            listed = ", ".join(f"{s} ({n} packets)" for s, n in sorted(many.items(), key=lambda x: -x[1])[:4])
            ip, _, port = str(self.source).partition(" -> port ")
            raise DataError(
                f"{self.root}: Velodyne data packets from {len(many) + 1} sources: {self.source} and {listed}; "
                f"split the capture per sensor, e.g. tcpdump -r IN -w OUT 'src host {ip} and udp dst port {port}'"
            )
        if self._others:
            log.warning(
                "%s: %d Velodyne data packets from other sources than %s dropped (%s)",
                self.root,
                sum(self._others.values()),
                self.source,
                ", ".join(sorted(self._others)),
            )

    def _hdl64e_calibration(self) -> None:
        """No factory byte: an HDL-64E S2/S3 carries its model and calibration in the status
        bytes of its data packets (velodyne_decoder's reading, on this sensor's packets only)."""
        vd = self._vd
        factory = [p[-2:] for _t, p in itertools.islice(self._packets(), 5)]
        if len(factory) < 5 or all(b == factory[0] for b in factory):
            return  # not an HDL-64E: the decoder's own default
        try:
            import yaml

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                metadata = vd.hdl64e.read_status_info(p for _t, p in self._packets())
            calib = vd.hdl64e.status_info_to_calib_dict(metadata)
        except (ValueError, KeyError, struct.error) as exc:
            raise DataError(f"{self.root}: HDL-64E capture whose calibration cannot be read: {exc}") from exc
        if calib["status"]["Calibration Time"] is None or [x["laser_id"] for x in calib["lasers"]] != list(range(64)):
            raise DataError(
                f"{self.root}: HDL-64E capture without a complete calibration in its status bytes "
                "(give the sensor's calibration file)"
            )
        self.model = "HDL64E_S2" if calib["status"]["Model"] == "S2" else "HDL64E_S3"
        self.calibration = vd.Calibration.from_string(yaml.dump(calib))

    def _config(self):
        vd = self._vd
        config = vd.Config()
        if self.model is not None:
            config.model = getattr(vd.Model, self.model)
        if self.calibration is not None:
            config.calibration = self.calibration
        return config

    def _sweeps(self) -> Iterator[tuple[float, np.ndarray]]:
        """(stamp in s, structured points) for every sweep of the capture's sensor, in order."""
        try:
            decoder = self._vd.StreamDecoder(self._config())
            for t, payload in self._packets():
                result = decoder.decode(t, payload, True)
                if result is not None:
                    yield _stamp(result[0]), result[1]
            result = decoder.finish(True)
            if result is not None:
                yield _stamp(result[0]), result[1]
        except (ValueError, RuntimeError) as exc:
            msg = " ".join(str(exc).split()) or type(exc).__name__
            raise DataError(f"{self.root}: cannot decode Velodyne pcap: {msg}") from exc

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
        return self.scan_of(i % self._n, stamp, pts)

    def scan_of(self, i: int, stamp: float, pts: np.ndarray) -> Scan:
        """Sweep ``i`` (its stamp and decoded points) organised into a Scan (live runs too)."""
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


class VelodyneScanSequence(VelodynePcapSequence):
    """The sweeps of a recording of raw Velodyne packets (``velodyne_msgs/VelodyneScan``, as
    ``rosbag record /velodyne_packets`` stores them): the packets of every message go through the
    decoder exactly as a capture's would (:class:`VelodynePcapSequence`), stamped with the packet
    stamps; ROS 1 ``.bag``, ROS 2 and MCAP recordings.

    Parameters
    ----------
    path : the recording (see :class:`data_tools.formats.rosbag.RosbagSequence`)
    topic : the VelodyneScan topic (needed when there are several)
    """

    format = "velodyne-pcap"

    def __init__(self, path: str | Path, topic: str, *, model: str | None = None) -> None:
        self.topic = topic
        super().__init__(path, model=model)

    def _packets(self) -> Iterator[tuple[float, bytes]]:
        from data_tools.formats.rosbag import open_reader, reader_paths

        self.source = self.topic
        try:
            with open_reader(reader_paths(self.root)) as reader:
                conns = [c for c in reader.connections if c.topic == self.topic]
                for conn, _t, raw in reader.messages(connections=conns):
                    msg = reader.deserialize(raw, conn.msgtype)
                    for packet in msg.packets:
                        data = np.asarray(packet.data, dtype=np.uint8).tobytes()
                        if is_data_packet(data):
                            yield int(packet.stamp.sec) + int(packet.stamp.nanosec) * 1e-9, data
        except DataError:
            raise
        except Exception as exc:  # rosbags raises many types for damaged recordings
            msg = " ".join(str(exc).split())[:300] or type(exc).__name__
            raise DataError(f"{self.root}: cannot read the packets of {self.topic}: {msg}") from exc
        self._others = {}
        self.truncated = False


def _stamp(stamp) -> float:
    """A sweep stamp (s): the sensor's clock when the decoder has it, else the capture's."""
    device = getattr(stamp, "device", None)
    return float(stamp.host if not device else device) if hasattr(stamp, "host") else float(stamp)


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


#: file endings of a packet capture
PCAP_SUFFIXES = (".pcap", ".pcapng")


def _is_velodyne_pcap(path: Path) -> bool:
    if path.is_dir() or path.suffix.lower() not in PCAP_SUFFIXES:
        return False
    check_capture(path)  # an empty or foreign file says so (not "no Ouster metadata")
    return looks_like_velodyne(path)


def _open_velodyne_pcap(path: Path, options: dict[str, Any]) -> Dataset:
    model = options.get("model")
    return VelodynePcapSequence(path, model=None if model is None else str(model))


READER = Reader("velodyne-pcap", ("model",), _is_velodyne_pcap, _open_velodyne_pcap)
