"""Replaying a packet capture onto the wire: its UDP payloads sent with their recorded spacing.

Velodyne and Ouster captures (any pcap / pcapng :class:`data_tools.formats.velodyne_pcap.Capture` reads):
the capture's main stream (the destination port carrying the most bytes: the lidar data; an
Ouster's IMU packets and a Velodyne's position packets are left out) is sent to one address,
loopback unless another host is named. ``rate`` scales the speed, ``loop`` repeats the capture,
``drop`` leaves out that fraction of packets at random (seeded), for fault tests.
"""

from __future__ import annotations

import random
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from data_tools.errors import DataError

#: packets due within this many seconds are sent at once (sleeping per packet is too coarse)
BURST_S = 0.002


@dataclass
class ReplayStats:
    sent: int = 0
    dropped: int = 0
    loops: int = 0
    seconds: float = 0.0
    port: int = 0


def parse_target(text: str, default_port: int | None) -> tuple[str, int | None]:
    """``udp://HOST[:PORT]`` → (host, port or None for the capture's own)."""
    scheme, sep, rest = text.partition("://")
    if not sep or scheme.lower() != "udp":
        raise ValueError(f"--to {text}: give udp://HOST[:PORT]")
    host, sep, port = rest.rstrip("/").rpartition(":")
    if not sep:
        return rest.rstrip("/") or "127.0.0.1", default_port
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"--to {text}: port {port!r} is not a number") from None
    if not 1 <= number <= 65535:
        raise ValueError(f"--to {text}: port {number} out of range 1..65535")
    return host.strip("[]") or "127.0.0.1", number


def main_port(path: Path, scan_packets: int = 4000) -> int:
    """The destination port carrying the most bytes among the capture's first packets."""
    from data_tools.formats.velodyne_pcap import Capture

    volume: Counter[int] = Counter()
    for _t, src, payload in Capture(path, max_packets=scan_packets):
        volume[int(src.rpartition(" ")[2])] += len(payload)
    if not volume:
        raise DataError(f"{path}: no UDP packets in the capture")
    return volume.most_common(1)[0][0]


def replay(
    path: str | Path,
    host: str = "127.0.0.1",
    port: int | None = None,
    *,
    rate: float = 1.0,
    loop: int = 1,
    drop: float = 0.0,
    seed: int = 0,
    stop: threading.Event | None = None,
) -> ReplayStats:
    """Send the capture's main stream to ``host:port`` (the capture's own port when None)."""
    from data_tools.formats.velodyne_pcap import Capture

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such capture")
    if rate <= 0:
        raise ValueError(f"--rate: must be positive, got {rate}")
    if not 0.0 <= drop < 1.0:
        raise ValueError(f"--drop: a fraction in [0, 1), got {drop}")
    stream = main_port(path)
    stats = ReplayStats(port=port or stream)
    rng = random.Random(seed)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 2**20)
    target = (host, stats.port)
    start = time.perf_counter()
    offset = 0.0  # seconds of capture already played (earlier loops)
    try:
        for k in range(loop):
            first = last = None
            for t, src, payload in Capture(path):
                if int(src.rpartition(" ")[2]) != stream:
                    continue
                if first is None:
                    first = t
                last = t
                due = start + (offset + t - first) / rate
                wait = due - time.perf_counter()
                if wait > BURST_S:
                    if stop is not None:
                        if stop.wait(wait - BURST_S / 2):
                            return stats
                    else:
                        time.sleep(wait - BURST_S / 2)
                if drop and rng.random() < drop:
                    stats.dropped += 1
                    continue
                sock.sendto(payload, target)
                stats.sent += 1
            if first is None:
                raise DataError(f"{path}: no packets to port {stream}")
            span = last - first
            offset += span + span / max(stats.sent, 1)  # one packet's spacing between loops
            stats.loops = k + 1
    finally:
        sock.close()
        stats.seconds = time.perf_counter() - start
    return stats


def replay_when_told(path: str | Path, conn, kwargs: dict) -> None:
    """Wait for a port on ``conn``, replay ``path`` to it on loopback, send the stats back (a
    replaying process started ahead of the receiver, for tests and demos)."""
    port = conn.recv()
    conn.send(replay(path, "127.0.0.1", int(port), **kwargs))
