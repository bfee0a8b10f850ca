"""Receiving sweeps on their own thread: UDP packets → decoding → whole sweeps → a bounded queue.

The receiver never waits on processing: it puts each completed sweep in a :class:`SweepQueue`,
which drops its oldest *whole* sweep when full (counted). Velodyne packets go through the same
``velodyne-decoder`` stream decoder as the offline reader (:mod:`data_tools.velodyne_pcap`), so
that a live run over a replayed capture cuts the same sweeps; the consumer organises them with the
offline reader's own :meth:`~data_tools.velodyne_pcap.VelodynePcapSequence.scan_of`.

Packet loss is counted per sweep from gaps in the packets' GPS timestamps; datagrams that are not
data packets of the sensor are skipped and counted; data packets from a second sender while the
first is still sending are an error naming both.
"""

from __future__ import annotations

import collections
import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from data_tools.errors import DataError

log = logging.getLogger("prc_slam")

#: a sender silent this long may be replaced by another one (a restarted replay), with a warning
SENDER_QUIET_S = 1.0
#: no packet for this long: a warning (repeated every such period of silence)
SILENCE_WARN_S = 2.0
#: nominal spacing of data packets in GPS microseconds (12 blocks of firings)
PACKET_PERIOD_US = {"HDL32E": 12 * 46.08, "VLP16": 12 * 2 * 55.296, "PuckHiRes": 12 * 2 * 55.296}
HOUR_US = 3_600_000_000


class LiveError(DataError):
    """The source cannot go on (e.g. a second sensor on the port); the message names the problem."""


@dataclass
class Sweep:
    """One whole sweep as received.

    Attributes
    ----------
    index : the sweep's number in the source (dropped ones counted), as the offline reader numbers them
    received : ``time.perf_counter()`` when its last packet was received (or the recording's frame read)
    stamp, points : the decoder's sweep stamp (s) and structured points (packet sources)
    scan : the Scan (recordings)
    lost_packets : packets missing inside this sweep
    """

    index: int
    received: float
    stamp: float = 0.0
    points: np.ndarray | None = None
    scan: Any = None
    lost_packets: int = 0
    flushed: bool = False  # completed by the end of the stream (no later packet)


class SweepQueue:
    """A bounded FIFO of whole sweeps; :meth:`put` never blocks: when full, the oldest sweep is
    dropped and counted (``dropped``)."""

    def __init__(self, maxsize: int = 1) -> None:
        if maxsize < 1:
            raise ValueError(f"--queue: must be at least 1, got {maxsize}")
        self.maxsize = maxsize
        self._items: collections.deque[Sweep] = collections.deque()
        self._cond = threading.Condition()
        self.dropped = 0
        self.put_count = 0
        self.closed = False

    def put(self, sweep: Sweep) -> None:
        with self._cond:
            if len(self._items) >= self.maxsize:
                self._items.popleft()
                self.dropped += 1
            self._items.append(sweep)
            self.put_count += 1
            self._cond.notify()

    def get(self, timeout: float) -> Sweep | None:
        """The oldest sweep, waiting at most ``timeout`` s (None: none came, or closed and empty)."""
        with self._cond:
            if not self._items and not self.closed:
                self._cond.wait(timeout)
            return self._items.popleft() if self._items else None

    def close(self) -> None:
        """No more sweeps will come; waiting getters return."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)


@dataclass
class ReceiverStats:
    """Counts kept by a receiver (read by the consumer and the status line)."""

    packets: int = 0
    foreign_packets: int = 0
    lost_packets: int = 0
    sweeps: int = 0
    timed: int = 0  # sweeps completed by a packet (the rate's)
    first_sweep: float | None = None  # perf_counter of the first / last sweep completed
    last_sweep: float | None = None
    last_packet: float | None = None  # perf_counter of the last datagram of the sensor
    sender: str | None = None
    warnings: list[str] = field(default_factory=list)

    def sweep_done(self, now: float) -> None:
        self.sweeps += 1
        self.timed += 1
        if self.first_sweep is None:
            self.first_sweep = now
        self.last_sweep = now

    def rate_in(self) -> float | None:
        """Sweeps per second between the first and the last completed sweep."""
        if self.sweeps < 2 or self.first_sweep is None or self.last_sweep is None:
            return None
        span = self.last_sweep - self.first_sweep
        return (self.timed - 1) / span if span > 0 and self.timed > 1 else None


class VelodyneAssembler:
    """Velodyne data packets → whole sweeps, with the offline reader's decoder and settings.

    The model comes from the first data packet's factory byte; ``scan_of`` organises a sweep as
    :class:`~data_tools.velodyne_pcap.VelodynePcapSequence` does (same organiser, same names).
    """

    def __init__(self, name: str, model: str | None = None) -> None:
        self.name = name
        self.forced_model = model
        self.reader: Any = None  # a VelodynePcapSequence set up for the model, without a file
        self.decoder: Any = None
        self.index = 0
        self.lost = 0  # in the sweep being assembled
        self._last_gps: int | None = None
        self._period_us: float | None = None

    def _start(self, payload: bytes) -> None:
        import velodyne_decoder as vd

        from data_tools.organize import Organizer
        from data_tools.velodyne_pcap import FACTORY_MODELS, MODEL_LASERS, VelodynePcapSequence

        entry = FACTORY_MODELS.get(payload[-1])
        model = self.forced_model or (None if entry is None else entry[0])
        if model is None:
            raise LiveError(
                f"{self.name}: data packets without a known factory byte (0x{payload[-1]:02x}; an HDL-64E?): "
                "give --model"
            )
        reader = VelodynePcapSequence.__new__(VelodynePcapSequence)
        reader._vd = vd
        reader.root = self.name
        reader.model = model
        reader.calibration = None
        reader.rows = MODEL_LASERS.get(model)
        reader.organizer = Organizer(rows=reader.rows, source_name=self.name)
        self.reader = reader
        self.decoder = vd.StreamDecoder(reader._config())
        self._period_us = PACKET_PERIOD_US.get(model)
        log.info(f"{self.name}: {model} data packets")

    def _count_lost(self, payload: bytes) -> None:
        gps = int.from_bytes(payload[1200:1204], "little")
        if self._last_gps is not None and self._period_us:
            gap = (gps - self._last_gps) % HOUR_US
            missing = round(gap / self._period_us) - 1
            if 0 < missing < 100_000:
                self.lost += missing
        self._last_gps = gps

    def feed(self, payload: bytes, now_wall: float) -> tuple[float, np.ndarray, int] | None:
        """Decode one data packet; a completed sweep as (stamp, points, lost packets), else None."""
        from data_tools.velodyne_pcap import _stamp

        if self.reader is None:
            self._start(payload)
        elif self.decoder is None:  # packets again after finish(): a new stream
            self.decoder = self.reader._vd.StreamDecoder(self.reader._config())
            self._last_gps = None
        self._count_lost(payload)
        result = self.decoder.decode(now_wall, payload, True)
        if result is None:
            return None
        lost, self.lost = self.lost, 0
        return _stamp(result[0]), result[1], lost

    def finish(self) -> tuple[float, np.ndarray, int] | None:
        """The sweep being assembled, as it is (the end of the stream), else None."""
        from data_tools.velodyne_pcap import _stamp

        if self.decoder is None:
            return None
        result = self.decoder.finish(True)
        self.decoder = None
        if result is None or len(result[1]) == 0:
            return None
        lost, self.lost = self.lost, 0
        return _stamp(result[0]), result[1], lost

    def scan_of(self, sweep: Sweep):
        """The Scan of a received sweep (the offline reader's organisation)."""
        return self.reader.scan_of(sweep.index, sweep.stamp, sweep.points)


def is_velodyne_data(payload: bytes) -> bool:
    from data_tools.velodyne_pcap import is_data_packet

    return is_data_packet(payload)


class UdpReceiver(threading.Thread):
    """Receives a sensor's UDP packets on ``host:port`` and puts whole sweeps in ``queue``.

    Parameters
    ----------
    host, port : where to listen (port 0: a free port, see :attr:`port` after :meth:`bind`)
    assembler : turns accepted packets into sweeps (``feed``, ``scan_of``)
    accept : payload → True for the sensor's data packets (others are counted as foreign)
    queue : the bounded sweep queue
    """

    def __init__(
        self,
        host: str,
        port: int,
        assembler: Any,
        accept: Callable[[bytes], bool],
        queue: SweepQueue,
        name: str = "",
    ) -> None:
        super().__init__(name="prc-slam-receiver", daemon=True)
        self.host, self.port = host, port
        self.assembler = assembler
        self.accept = accept
        self.queue = queue
        self.label = name or f"{host}:{port}"
        self.stats = ReceiverStats()
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self.sock: socket.socket | None = None
        self._last_seen: dict[str, float] = {}
        self._lock = threading.Lock()

    def bind(self) -> None:
        """Open and bind the socket (an OSError names the address)."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        for opt in (33, socket.SO_RCVBUF):  # SO_RCVBUFFORCE (root), else up to rmem_max
            try:
                sock.setsockopt(socket.SOL_SOCKET, opt, 32 * 2**20)
                break
            except OSError:
                continue
        try:
            sock.bind((self.host, self.port))
        except OSError as exc:
            sock.close()
            raise OSError(f"{self.label}: cannot listen on {self.host}:{self.port}: {exc.strerror or exc}") from None
        sock.settimeout(0.2)
        self.sock = sock
        self.port = sock.getsockname()[1]

    def stop(self) -> None:
        self.stop_event.set()

    def run(self) -> None:
        assert self.sock is not None
        silent_since = time.perf_counter()
        warned = 0
        try:
            while not self.stop_event.is_set():
                try:
                    data, addr = self.sock.recvfrom(65535)
                except TimeoutError:
                    quiet = time.perf_counter() - silent_since
                    if quiet >= SILENCE_WARN_S * (warned + 1):
                        warned += 1
                        msg = f"{self.label}: no packets for {quiet:.0f} s; still waiting"
                        self.stats.warnings.append(msg)
                        log.warning(msg)
                    continue
                now = time.perf_counter()
                self.handle(data, addr, now)
                silent_since, warned = now, 0
        except LiveError as exc:
            self.error = exc
        except Exception as exc:  # a decoder failure ends the run with its message, never silently
            self.error = LiveError(f"{self.label}: {type(exc).__name__}: {exc}")
        finally:
            self.sock.close()

    def handle(self, data: bytes, addr: tuple[str, int], now: float) -> None:
        """One datagram: a data packet of the sensor is decoded; anything else is counted."""
        if not self.accept(data):
            self.stats.foreign_packets += 1
            return
        sender = f"{addr[0]}:{addr[1]}"
        self._check_sender(sender, now)
        self.stats.packets += 1
        self.stats.last_packet = now
        with self._lock:
            done = self.assembler.feed(data, time.time())
        if done is not None:
            self._put(done, now)

    def flush(self) -> bool:
        """Queue the sweep being assembled (the stream has ended); True when there was one."""
        finish = getattr(self.assembler, "finish", None)
        if finish is None:
            return False
        with self._lock:
            done = finish()
        if done is None:
            return False
        self._put(done, time.perf_counter(), flushed=True)
        return True

    def _put(self, done: tuple[float, np.ndarray, int], now: float, flushed: bool = False) -> None:
        stamp, points, lost = done
        self.stats.lost_packets += lost
        if flushed:  # completed by the end of the stream, not by a packet: no rate
            self.stats.sweeps += 1
        else:
            self.stats.sweep_done(now)
        index = self.assembler.index
        self.assembler.index += 1
        self.queue.put(Sweep(index, now, stamp, points, lost_packets=lost, flushed=flushed))

    def _check_sender(self, sender: str, now: float) -> None:
        first = self.stats.sender
        if first is None:
            self.stats.sender = sender
        elif sender != first:
            if now - self._last_seen.get(first, 0.0) < SENDER_QUIET_S:
                raise LiveError(
                    f"{self.label}: data packets from two sensors on port {self.port}: {first} and {sender}; "
                    "give each sensor its own port"
                )
            msg = f"{self.label}: the sender changed from {first} to {sender} (the first was silent)"
            self.stats.warnings.append(msg)
            log.warning(msg)
            self.stats.sender = sender
        self._last_seen[sender] = now


class RealtimeReader(threading.Thread):
    """A recording as a stand-in sensor: its frames read and put in ``queue`` at their recorded
    rate (``times`` of the dataset, else ``period``), scaled by ``rate``."""

    def __init__(self, dataset: Any, n: int, queue: SweepQueue, rate: float = 1.0, period: float = 0.1) -> None:
        super().__init__(name="prc-slam-realtime", daemon=True)
        self.dataset, self.n, self.queue, self.rate = dataset, n, queue, rate
        times = getattr(dataset, "times", None)
        t = None if times is None else np.asarray(times, dtype=np.float64)[:n]
        if t is None or len(t) != n or not (np.diff(t) > 0).all():
            t = np.arange(n) * period
        self.offsets = (t - t[0]) / rate
        self.stats = ReceiverStats(sender=str(getattr(dataset, "root", "")))
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self.finished = False

    def stop(self) -> None:
        self.stop_event.set()

    def run(self) -> None:
        from prc_slam.pipeline import FrameError

        start = time.perf_counter()
        try:
            for i in range(self.n):
                wait = start + self.offsets[i] - time.perf_counter()
                if wait > 0 and self.stop_event.wait(wait):
                    return
                if self.stop_event.is_set():
                    return
                try:
                    scan = self.dataset[i]
                except Exception as exc:  # an unreadable frame: skipped and counted by the pipeline
                    scan = FrameError(str(exc))
                now = time.perf_counter()
                self.stats.packets += 1
                self.stats.last_packet = now
                self.stats.sweep_done(now)
                self.queue.put(Sweep(i, now, scan=scan))
        except BaseException as exc:
            self.error = exc
        finally:
            self.finished = True
            self.queue.close()
