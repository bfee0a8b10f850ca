"""Receiving sweeps on their own thread or process: UDP packets → decoding → whole sweeps → a
bounded queue.

The receiver never waits on processing: it puts each completed sweep in a :class:`SweepQueue`,
which drops its oldest *whole* sweep when full (counted). Velodyne packets go through the same
``velodyne-decoder`` stream decoder as the offline reader (:mod:`data_tools.formats.velodyne_pcap`), so
that a live run over a replayed capture cuts the same sweeps; the consumer organises them with the
offline reader's own :meth:`~data_tools.formats.velodyne_pcap.VelodynePcapSequence.scan_of`.

Packet loss is counted per sweep from gaps in the packets' GPS timestamps; datagrams that are not
data packets of the sensor are skipped and counted; data packets from a second sender while the
first is still sending are an error naming both.
"""

from __future__ import annotations

import collections
import logging
import socket
import struct
import sys
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
#: nominal spacing of data packets in GPS microseconds (12 blocks of firings); packets of other
#: models are not checked for gaps (``lost_packets`` stays 0)
PACKET_PERIOD_US = {
    "HDL32E": 12 * 46.08,
    "VLP16": 12 * 2 * 55.296,
    "PuckHiRes": 12 * 2 * 55.296,
    "VLP32C": 12 * 55.296,
}
HOUR_US = 3_600_000_000
#: Linux: kernel receive stamps of datagrams (struct timespec), SO_TIMESTAMPNS / SCM_TIMESTAMPNS
SO_TIMESTAMPNS = SCM_TIMESTAMPNS = 35


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
    :class:`~data_tools.formats.velodyne_pcap.VelodynePcapSequence` does (same organiser, same names).
    """

    def __init__(self, name: str, model: str | None = None) -> None:
        self.name = name
        self.forced_model = model
        self.reader: Any = None  # a VelodynePcapSequence set up for the model, without a file
        self.model: str | None = None
        self.decoder: Any = None
        self.index = 0
        self.lost = 0  # in the sweep being assembled
        self._last_gps: int | None = None
        self._period_us: float | None = None

    def _start(self, payload: bytes) -> None:
        from data_tools.formats.velodyne_pcap import FACTORY_MODELS

        entry = FACTORY_MODELS.get(payload[-1])
        model = self.forced_model or (None if entry is None else entry[0])
        if model is None:
            raise LiveError(
                f"{self.name}: data packets without a known factory byte (0x{payload[-1]:02x}; an HDL-64E?): "
                "give --model"
            )
        self.setup(model)
        self.decoder = self.reader._vd.StreamDecoder(self.reader._config())
        log.info(f"{self.name}: {model} data packets")

    def setup(self, model: str) -> None:
        """The offline reader's settings for ``model`` (no decoder; the organiser comes with the first
        :meth:`scan_of`)."""
        import velodyne_decoder as vd

        from data_tools.formats.velodyne_pcap import MODEL_LASERS, VelodynePcapSequence

        reader = VelodynePcapSequence.__new__(VelodynePcapSequence)
        reader._vd = vd
        reader.root = self.name
        reader.model = model
        reader.calibration = None
        reader.rows = MODEL_LASERS.get(model)
        reader.organizer = None  # made by scan_of, in the process that organises
        self.reader = reader
        self.model = model
        self._period_us = PACKET_PERIOD_US.get(model)

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
        from data_tools.formats.velodyne_pcap import _stamp

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
        from data_tools.formats.velodyne_pcap import _stamp

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
        if self.reader.organizer is None:
            from data_tools.organize import Organizer

            self.reader.organizer = Organizer(rows=self.reader.rows, source_name=self.name)
        return self.reader.scan_of(sweep.index, sweep.stamp, sweep.points)


def is_velodyne_data(payload: bytes) -> bool:
    from data_tools.formats.velodyne_pcap import is_data_packet

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
        self._stamped = False
        if sys.platform.startswith("linux"):
            try:
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self._stamped = True
            except OSError:
                pass
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
                    data, addr, wall = self._receive()
                except TimeoutError:
                    quiet = time.perf_counter() - silent_since
                    if quiet >= SILENCE_WARN_S * (warned + 1):
                        warned += 1
                        msg = f"{self.label}: no packets for {quiet:.0f} s; still waiting"
                        self.stats.warnings.append(msg)
                        log.warning(msg)
                    continue
                now = time.perf_counter()
                # received when the kernel stamped it (our own stalls are part of the latency)
                arrived = now - max(0.0, time.time() - wall)
                self.handle(data, addr, arrived, wall)
                silent_since, warned = now, 0
        except LiveError as exc:
            self.error = exc
        except Exception as exc:  # a decoder failure ends the run with its message, never silently
            self.error = LiveError(f"{self.label}: {type(exc).__name__}: {exc}")
        finally:
            self.sock.close()

    def _receive(self) -> tuple[bytes, tuple[str, int], float]:
        """One datagram, its sender and its arrival (wall clock, s): the kernel's receive stamp
        where there is one, so that the decoder's host times do not depend on this process's
        scheduling (the decoder cuts a sweep at a gap in them), else the time it is read."""
        if not self._stamped:
            data, addr = self.sock.recvfrom(65535)
            return data, addr, time.time()
        data, anc, _flags, addr = self.sock.recvmsg(65535, 64)
        for level, kind, payload in anc:
            if level == socket.SOL_SOCKET and kind == SCM_TIMESTAMPNS and len(payload) >= 16:
                sec, nsec = struct.unpack("qq", payload[:16])
                return data, addr, sec + nsec * 1e-9
        return data, addr, time.time()

    def handle(self, data: bytes, addr: tuple[str, int], now: float, wall: float | None = None) -> None:
        """One datagram (``now``: its arrival on ``time.perf_counter()``, ``wall``: on the wall
        clock): a data packet of the sensor is decoded; anything else is counted."""
        if not self.accept(data):
            self.stats.foreign_packets += 1
            return
        sender = f"{addr[0]}:{addr[1]}"
        self._check_sender(sender, now)
        self.stats.packets += 1
        self.stats.last_packet = now
        with self._lock:
            done = self.assembler.feed(data, time.time() if wall is None else wall)
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


# ---------------------------------------------------------------------------------------------
# the Velodyne receiver in its own process


class _LockedConn:
    """A pipe end whose ``send`` may be called from several threads."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn
        self._lock = threading.Lock()

    def send(self, msg: Any) -> None:
        with self._lock:
            self.conn.send(msg)

    def poll(self, timeout: float) -> bool:
        return self.conn.poll(timeout)

    def recv(self) -> Any:
        return self.conn.recv()


class _PipeQueue:
    """The child's side of the sweep queue: every sweep goes to the parent at once."""

    def __init__(self, conn: Any, receiver: UdpReceiver) -> None:
        self.conn, self.receiver = conn, receiver

    def put(self, sweep: Sweep) -> None:
        self.conn.send(("sweep", sweep, self.receiver.assembler.model, _stats_of(self.receiver.stats)))


def _stats_of(stats: ReceiverStats) -> dict[str, Any]:
    return {k: getattr(stats, k) for k in ("packets", "foreign_packets", "lost_packets", "last_packet", "sender")}


class _ChildLog(logging.Handler):
    """The child's warnings, sent to the parent (which logs them)."""

    def __init__(self, conn: Any) -> None:
        super().__init__(logging.INFO)
        self.conn = conn

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.conn.send(("log", record.levelno, record.getMessage()))
        except (OSError, ValueError):  # pragma: no cover - the parent has gone
            pass


def _receiver_main(host: str, port: int, name: str, model: str | None, conn: Any, stop: Any) -> None:
    """The receiving process: listens, decodes, sends whole sweeps and counts to the parent."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops this process
    conn = _LockedConn(conn)
    log.handlers[:] = [_ChildLog(conn)]
    log.setLevel(logging.INFO)
    log.propagate = False
    rx = UdpReceiver(host, port, VelodyneAssembler(name, model), is_velodyne_data, None, name)  # type: ignore[arg-type]
    rx.queue = _PipeQueue(conn, rx)  # type: ignore[assignment]
    try:
        rx.bind()
    except OSError as exc:
        conn.send(("error", str(exc)))
        return
    conn.send(("ready", rx.port))
    rx.stop_event = stop
    watcher = threading.Thread(target=_serve_commands, args=(rx, conn), daemon=True)
    watcher.start()
    rx.run()
    if rx.error is not None:
        conn.send(("error", str(rx.error)))
    conn.send(("stats", _stats_of(rx.stats), list(rx.stats.warnings)))
    conn.send(("end",))


def _serve_commands(rx: UdpReceiver, conn: Any) -> None:
    """The parent's requests to the child: ``flush`` (the stream has ended) and heartbeats of counts."""
    while not rx.stop_event.is_set():
        try:
            if conn.poll(0.25):
                msg = conn.recv()
            else:
                msg = None
        except (EOFError, OSError):  # the parent has gone: no one to receive for
            rx.stop_event.set()
            return
        if msg is not None:
            if msg == "flush":
                done = rx.flush()
                conn.send(("flushed", done))
        try:
            conn.send(("stats", _stats_of(rx.stats), None))
        except (EOFError, OSError):
            rx.stop_event.set()
            return


class ProcessReceiver(threading.Thread):
    """A Velodyne receiver in its own process (spawned): the socket, the decoding and the sweep
    assembly never wait for the GIL that KISS-ICP holds while it registers, and take nothing from
    the processing's. This thread takes the sweeps it sends into ``queue`` (dropping the oldest
    when full); the interface is :class:`UdpReceiver`'s."""

    def __init__(self, host: str, port: int, name: str, model: str | None, queue: SweepQueue) -> None:
        super().__init__(name="prc-slam-receiver-pipe", daemon=True)
        import multiprocessing as mp

        self.host, self.port, self.label = host, port, name
        self.queue = queue
        self.assembler = VelodyneAssembler(name, model)
        self.stats = ReceiverStats()
        self.error: BaseException | None = None
        self._ctx = mp.get_context("spawn")
        self._stop_event = self._ctx.Event()
        self._conn, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(
            target=_receiver_main, args=(host, port, name, model, child, self._stop_event), name="prc-slam-receiver",
            daemon=True,
        )  # fmt: skip
        self._flushed = threading.Event()
        self._flush_result = False
        self._send_lock = threading.Lock()

    def bind(self, timeout: float = 60.0) -> None:
        """Start the receiving process and wait until it listens (an OSError names the address)."""
        self._proc.start()
        if not self._conn.poll(timeout):
            self._kill()
            raise OSError(f"{self.label}: the receiving process did not start within {timeout:g} s")
        msg = self._conn.recv()
        if msg[0] == "error":
            self._kill()
            raise OSError(msg[1])
        self.port = int(msg[1])

    def _kill(self) -> None:
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(timeout=5)
        if self._proc.is_alive():  # pragma: no cover - a child ignoring SIGTERM
            self._proc.kill()
            self._proc.join(timeout=5)

    def run(self) -> None:
        try:
            while True:
                try:
                    msg = self._conn.recv()
                except (EOFError, OSError):
                    break
                kind = msg[0]
                if kind == "sweep":
                    _kind, sweep, model, stats = msg
                    if self.assembler.reader is None:
                        self.assembler.setup(model)
                    self._update(stats)
                    if sweep.flushed:
                        self.stats.sweeps += 1
                    else:
                        self.stats.sweep_done(sweep.received)
                    self.queue.put(sweep)
                elif kind == "stats":
                    self._update(msg[1])
                elif kind == "log":
                    log.log(msg[1], msg[2])
                    if msg[1] >= logging.WARNING:
                        self.stats.warnings.append(msg[2])
                elif kind == "flushed":
                    self._flush_result = bool(msg[1])
                    self._flushed.set()
                elif kind == "error":
                    self.error = LiveError(msg[1])
                elif kind == "end":
                    break
        finally:
            self._flushed.set()

    def _update(self, stats: dict[str, Any]) -> None:
        for k, v in stats.items():
            setattr(self.stats, k, v)

    def flush(self) -> bool:
        """Have the process queue the sweep being assembled; True when there was one."""
        if not self._proc.is_alive():
            return False
        self._flushed.clear()
        with self._send_lock:
            self._conn.send("flush")
        self._flushed.wait(5.0)
        return self._flush_result

    def stop(self) -> None:
        self._stop_event.set()

    def join(self, timeout: float | None = None) -> None:
        self._stop_event.set()
        self._proc.join(timeout=timeout)
        if self._proc.is_alive():
            self._kill()
        super().join(timeout=timeout)
