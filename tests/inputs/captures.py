"""Capture files around given frames: Ethernet / IPv4 / UDP frames, classic pcap (any link type, byte
order, time resolution) and pcapng."""

from __future__ import annotations

import struct
from pathlib import Path


def eth_udp(payload: bytes, port: int, src: tuple[int, int, int, int] = (192, 168, 1, 201), proto: int = 17) -> bytes:
    """An Ethernet / IPv4 frame around a UDP datagram (or around ``payload`` as is for another protocol)."""
    body = struct.pack(">HHHH", port, port, 8 + len(payload), 0) + payload if proto == 17 else payload
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(body), 0, 0, 64, proto, 0, bytes(src), b"\xff" * 4) + body
    return b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x01" + b"\x08\x00" + ip


def write_frames_pcap(
    path: Path, frames: list[tuple[float, bytes]], *, nano: bool = False, big: bool = False, link: int = 1
) -> Path:
    """Classic libpcap, micro- or nanosecond stamps, either byte order (``link``: the frames' link type)."""
    e = ">" if big else "<"
    with path.open("wb") as f:
        f.write(struct.pack(e + "IHHiIII", 0xA1B23C4D if nano else 0xA1B2C3D4, 2, 4, 0, 0, 65535, link))
        for s, eth in frames:
            frac = round(s % 1 * (1e9 if nano else 1e6))
            f.write(struct.pack(e + "IIII", int(s), frac, len(eth), len(eth)) + eth)
    return path


def write_pcapng(path: Path, frames: list[tuple[float, bytes]], *, tsresol: int | None = None) -> Path:
    """pcapng: section header, one Ethernet interface (``if_tsresol`` 10^-tsresol s when given),
    one enhanced packet block per frame."""

    def block(btype: int, body: bytes) -> bytes:
        body += b"\x00" * (-len(body) % 4)
        return struct.pack("<II", btype, 12 + len(body)) + body + struct.pack("<I", 12 + len(body))

    unit = 10.0 ** -(tsresol or 6)
    options = b"" if tsresol is None else struct.pack("<HHB3x", 9, 1, tsresol) + struct.pack("<HH", 0, 0)
    with path.open("wb") as f:
        f.write(block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1)))
        f.write(block(1, struct.pack("<HHI", 1, 0, 65535) + options))
        for s, eth in frames:
            ts = round(s / unit)
            f.write(block(6, struct.pack("<IIIII", 0, ts >> 32, ts & 0xFFFFFFFF, len(eth), len(eth)) + eth))
    return path
