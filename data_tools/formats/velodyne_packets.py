"""Velodyne VLP-16 and HDL-32E data packets from simulated sweeps, and a classic pcap writer.

The packets are the sensors' own format, as ``velodyne-decoder`` (and the ROS driver) read it:
1206-byte UDP payloads of 12 blocks of 100 bytes (flag ``0xFFEE``, azimuth in 0.01 deg, then 32
channels of distance in 2 mm units and a reflectivity byte), a 4-byte GPS timestamp
(microseconds since the top of the hour) and two factory bytes: return mode ``0x37``
(strongest) and the model (``0x22`` VLP-16, ``0x21`` HDL-32E). An HDL-32E block holds one
firing of its 32 lasers; a VLP-16 block holds two firings of its 16 lasers (the decoder
interpolates the second firing's azimuth half-way to the next block's).

A Velodyne spins clockwise seen from above: its azimuth grows with time while the angle in the
x-forward, y-left frame falls. The simulated sensor must therefore be made with
``clockwise=True`` (:func:`data_tools.sim.sensors.make_sensor`), so that the firing order of the
packets is the simulated firing order. Column ``c`` of a sweep is block azimuth
``-degrees(azimuth of c)``; rows go to the laser whose calibrated elevation is nearest
(the decoder's bundled calibration of the model). The decoder adds each laser's firing-time
azimuth offset within a block (at most 0.13 deg at 10 Hz), so decoded points lie within that and
the 2 mm range quantisation of the simulated ones.

The packet stream runs across sweeps as a sensor's does (a packet may hold the end of one sweep
and the start of the next); the tail of the last sweep that does not fill a packet is not sent.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from data_tools.errors import DataError

PACKET_SIZE = 1206
BLOCKS = 12
CHANNELS = 32
DISTANCE_UNIT = 0.002  # m
RETURN_STRONGEST = 0x37
HOUR_US = 3_600_000_000
#: pcap stamps of a simulated capture: this epoch (s) plus the simulated time
EPOCH = 1_700_002_800.0  # a top of the hour, so that GPS and pcap clocks agree to the microsecond


@dataclass(frozen=True)
class PacketFormat:
    """The data-packet layout of one Velodyne model."""

    name: str  # velodyne_decoder model name
    factory: int  # model byte
    lasers: int
    firings_per_block: int
    calibration: str  # velodyne_decoder's bundled calibration file

    @property
    def columns_per_packet(self) -> int:
        return BLOCKS * self.firings_per_block


FORMATS = {
    "vlp16": PacketFormat("VLP16", 0x22, 16, 2, "VLP-16.yml"),
    "hdl32": PacketFormat("HDL32E", 0x21, 32, 1, "HDL-32E.yml"),
}


def laser_elevations(fmt: PacketFormat) -> np.ndarray:
    """Elevation (rad) of each laser id, from velodyne-decoder's bundled calibration."""
    import importlib.resources

    import yaml

    text = (importlib.resources.files("velodyne_decoder.calibrations") / fmt.calibration).read_text()
    lasers = yaml.safe_load(text)["lasers"]
    elev = np.zeros(len(lasers))
    for laser in lasers:
        elev[int(laser["laser_id"])] = float(laser["vert_correction"])
    return elev


def lasers_of_rows(altitude: np.ndarray, fmt: PacketFormat, tolerance_deg: float = 0.1) -> np.ndarray:
    """The laser id of every row of a range image with beam elevations ``altitude`` (rad).

    Raises
    ------
    DataError
        The rows are not the model's lasers (count, or an elevation further than
        ``tolerance_deg`` from every laser's).
    """
    elev = laser_elevations(fmt)
    altitude = np.asarray(altitude, dtype=np.float64)
    if len(altitude) != fmt.lasers:
        raise DataError(f"{fmt.name} packets need {fmt.lasers} beams, the sweep has {len(altitude)}")
    ids = np.abs(altitude[:, None] - elev[None, :]).argmin(axis=1)
    off = np.degrees(np.abs(altitude - elev[ids]))
    if len(set(ids.tolist())) != len(ids) or off.max() > tolerance_deg:
        raise DataError(
            f"the beam elevations are not those of a {fmt.name} (worst {off.max():.3f} deg from its lasers)"
        )
    return ids


class PacketEncoder:
    """Turns range images into a stream of data packets (stamp in s, 1206-byte payload).

    Parameters
    ----------
    fmt : the model's :class:`PacketFormat`
    altitude : beam elevation (rad) of each row
    azimuth : the column azimuths (rad, x-forward y-left, falling with the column: clockwise)
    epoch : added to the simulated times for the packets' capture stamps (s)
    """

    def __init__(self, fmt: PacketFormat, altitude: np.ndarray, azimuth: np.ndarray, epoch: float = EPOCH) -> None:
        azimuth = np.asarray(azimuth, dtype=np.float64)
        step = np.angle(np.exp(1j * np.diff(azimuth)))
        if len(step) and not (step < 0).all():
            raise DataError(
                "Velodyne packets need a sensor spinning clockwise (azimuth falling with the column); "
                "simulate it with clockwise=True"
            )
        self.fmt = fmt
        self.laser = lasers_of_rows(altitude, fmt)
        self.block_azimuth = np.round(np.degrees(-azimuth) % 360.0 * 100.0).astype(np.int64) % 36000
        self.epoch = float(epoch)
        n = fmt.lasers
        self._dist = np.zeros((n, 0), np.uint16)  # per laser id, the columns not yet sent
        self._refl = np.zeros((n, 0), np.uint8)
        self._az = np.zeros(0, np.int64)
        self._t = np.zeros(0, np.float64)
        self.packets = 0

    def add_sweep(
        self, ranges: np.ndarray, intensity: np.ndarray | None, times: np.ndarray
    ) -> list[tuple[float, bytes]]:
        """The packets completed by one sweep (``ranges``, ``intensity`` ``[rows, cols]``;
        ``times``: the firing time (s) of each column)."""
        r = np.asarray(ranges, dtype=np.float64)
        units = np.round(np.nan_to_num(r, nan=0.0, posinf=0.0) / DISTANCE_UNIT)
        units[(r <= 0) | (units > 65535)] = 0
        dist = np.zeros(r.shape, np.uint16)
        dist[self.laser] = units.astype(np.uint16)
        refl = np.zeros(r.shape, np.uint8)
        if intensity is not None:
            refl[self.laser] = np.clip(np.nan_to_num(np.asarray(intensity, np.float64)), 0, 255).astype(np.uint8)
        self._dist = np.concatenate([self._dist, dist], axis=1)
        self._refl = np.concatenate([self._refl, refl], axis=1)
        self._az = np.concatenate([self._az, self.block_azimuth[: r.shape[1]]])
        self._t = np.concatenate([self._t, np.asarray(times, np.float64)])
        per = self.fmt.columns_per_packet
        full = self._dist.shape[1] // per
        if full == 0:
            return []
        m = full * per
        out = self._packets(self._dist[:, :m], self._refl[:, :m], self._az[:m], self._t[:m])
        self._dist, self._refl, self._az, self._t = self._dist[:, m:], self._refl[:, m:], self._az[m:], self._t[m:]
        return out

    def _packets(self, dist: np.ndarray, refl: np.ndarray, az: np.ndarray, t: np.ndarray) -> list[tuple[float, bytes]]:
        fpb, n = self.fmt.firings_per_block, self.fmt.lasers
        per = self.fmt.columns_per_packet
        k = dist.shape[1] // per
        arr = np.zeros(k, dtype=PACKET_DTYPE)
        blocks = arr["blocks"]  # (k, 12)
        blocks["flag"] = 0xEEFF  # bytes ff ee
        blocks["azimuth"] = az.reshape(k, BLOCKS, fpb)[:, :, 0]
        # channels of a block: firing 0's lasers, then firing 1's (VLP-16)
        d = dist.T.reshape(k, BLOCKS, fpb, n).reshape(k, BLOCKS, fpb * n)
        f = refl.T.reshape(k, BLOCKS, fpb, n).reshape(k, BLOCKS, fpb * n)
        blocks["channels"]["distance"] = d
        blocks["channels"]["reflectivity"] = f
        tt = t.reshape(k, per)
        arr["timestamp"] = np.round(tt[:, 0] * 1e6).astype(np.int64) % HOUR_US
        arr["mode"] = RETURN_STRONGEST
        arr["factory"] = self.fmt.factory
        raw = arr.tobytes()
        self.packets += k
        return [(self.epoch + float(tt[i, -1]), raw[i * PACKET_SIZE : (i + 1) * PACKET_SIZE]) for i in range(k)]


_CHANNEL = np.dtype([("distance", "<u2"), ("reflectivity", "u1")])
_BLOCK = np.dtype([("flag", "<u2"), ("azimuth", "<u2"), ("channels", _CHANNEL, (CHANNELS,))])
PACKET_DTYPE = np.dtype([("blocks", _BLOCK, (BLOCKS,)), ("timestamp", "<u4"), ("mode", "u1"), ("factory", "u1")])
assert PACKET_DTYPE.itemsize == PACKET_SIZE


def _checksum(header: bytes) -> int:
    s = sum(struct.unpack(f"!{len(header) // 2}H", header))
    s = (s >> 16) + (s & 0xFFFF)
    s += s >> 16
    return ~s & 0xFFFF


def udp_frame(payload: bytes, src: tuple[str, int], dst: tuple[str, int]) -> bytes:
    """An Ethernet / IPv4 / UDP frame carrying ``payload`` (UDP checksum 0: none)."""
    ip_src = bytes(int(x) for x in src[0].split("."))
    ip_dst = bytes(int(x) for x in dst[0].split("."))
    udp = struct.pack("!HHHH", src[1], dst[1], 8 + len(payload), 0) + payload
    ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0x4000, 64, 17, 0, ip_src, ip_dst)
    ip = ip[:10] + struct.pack("!H", _checksum(ip)) + ip[12:]
    eth = b"\xff\xff\xff\xff\xff\xff" + b"\x60\x76\x88\x00\x00\x01" + b"\x08\x00"
    return eth + ip + udp


class PcapWriter:
    """A classic libpcap file (microsecond stamps, Ethernet links) of UDP packets, written as it goes.

    Parameters
    ----------
    path : the ``.pcap`` written
    src, dst : sender and destination (IPv4 address, port) of every packet
    """

    def __init__(
        self,
        path: str | Path,
        src: tuple[str, int] = ("192.168.1.201", 2368),
        dst: tuple[str, int] = ("255.255.255.255", 2368),
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.src, self.dst = src, dst
        self._f = self.path.open("wb")
        self._f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
        self.packets = 0

    def write(self, stamp: float, payload: bytes) -> None:
        frame = udp_frame(payload, self.src, self.dst)
        sec = int(stamp)
        usec = round((stamp - sec) * 1e6)
        if usec >= 1_000_000:
            sec, usec = sec + 1, usec - 1_000_000
        self._f.write(struct.pack("<IIII", sec, usec, len(frame), len(frame)) + frame)
        self.packets += 1

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self) -> PcapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def capture_format(sensor: str) -> PacketFormat:
    """The packet format of a simulated sensor (``vlp16`` or ``hdl32``)."""
    if sensor not in FORMATS:
        raise DataError(f"--pcap: Velodyne packets are written for {' and '.join(FORMATS)}, not {sensor}")
    return FORMATS[sensor]


class SimCapture:
    """Writes the sweeps of a simulation (``SimFrame``) as a Velodyne capture, as they are made.

    Parameters
    ----------
    path : the ``.pcap``
    sensor : the simulator's sensor (:class:`data_tools.sim.sensors.SimSensor`, spinning clockwise)
    name : its simulator name (``vlp16``, ``hdl32``)
    """

    def __init__(self, path: str | Path, sensor, name: str) -> None:
        fmt = capture_format(name)
        model = sensor.model
        azimuth = model.azimuth0 + model.direction * 2.0 * np.pi * (np.arange(model.cols) + 0.5) / model.cols
        self.encoder = PacketEncoder(fmt, model.altitude, azimuth)
        self.writer = PcapWriter(path)

    def add(self, frame) -> None:
        """Write the packets completed by one simulated frame."""
        times = np.asarray(frame.slot_times)[0]
        for stamp, payload in self.encoder.add_sweep(frame.ranges, frame.intensity, times):
            self.writer.write(stamp, payload)

    def close(self) -> None:
        self.writer.close()
