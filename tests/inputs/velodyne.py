"""Data packets of a simulated VLP-16 in a round room, and the classic pcap file that carries them."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

VLP16_ELEVATION = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15], float)


FIRING = 55.296e-6  # s between VLP-16 firing sequences


def vlp16_stream(n_sweeps: float = 2.3, rpm: float = 600.0, dropout: float = 0.05, seed: int = 0):
    """Data packets of a simulated VLP-16 in a round room (walls 10-20 m, floor 1.8 m below).

    Returns the payloads, their capture stamps and one row per emitted measurement:
    (block, firing sequence, laser id, encoded range in m; 0 = no return).
    """
    rng = np.random.default_rng(seed)
    block_dt = 2 * FIRING
    deg_per_s = rpm / 60.0 * 360.0
    blocks = int(n_sweeps * 60.0 / rpm / block_dt) // 12 * 12
    t = np.arange(blocks) * block_dt
    az_block = (t * deg_per_s + 10.0) % 360.0
    # every measurement: (block, seq, laser)
    b, s, k = (a.ravel() for a in np.meshgrid(np.arange(blocks), np.arange(2), np.arange(16), indexing="ij"))
    az = np.radians(az_block[b] + s * FIRING * deg_per_s)
    el = np.radians(VLP16_ELEVATION[k])
    r = (15.0 + 5.0 * np.sin(3.0 * az)) / np.cos(el)
    floor = np.where(el < 0, 1.8 / np.maximum(-np.sin(el), 1e-9), np.inf)
    r = np.minimum(r, floor)
    r[rng.random(r.size) < dropout] = 0.0
    d = np.round(r / 0.002).astype(np.uint16)
    rec = np.zeros(blocks * 32, dtype=[("d", "<u2"), ("i", "u1")])
    rec["d"], rec["i"] = d, 100
    payloads, stamps = [], []
    for p0 in range(0, blocks, 12):
        buf = bytearray()
        for j in range(p0, p0 + 12):
            buf += b"\xff\xee" + struct.pack("<H", round(az_block[j] * 100) % 36000)
            buf += rec[j * 32 : (j + 1) * 32].tobytes()
        ts_us = int(t[p0] * 1e6)
        buf += struct.pack("<IBB", ts_us, 0x37, 0x22)  # strongest return, VLP-16
        payloads.append(bytes(buf))
        stamps.append(1.0e9 + t[p0])
    truth = np.column_stack([b, s, k, d * 0.002])
    return payloads, stamps, truth


def write_pcap(path: Path, payloads: list[bytes], stamps: list[float], port: int = 2368) -> Path:
    """A classic libpcap file: Ethernet / IPv4 / UDP around each payload."""
    with path.open("wb") as f:
        f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
        for p, s in zip(payloads, stamps, strict=True):
            udp = struct.pack(">HHHH", port, port, 8 + len(p), 0) + p
            src, dst = bytes([192, 168, 1, 201]), bytes([255, 255, 255, 255])
            ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0, 64, 17, 0, src, dst) + udp
            eth = b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x01" + b"\x08\x00" + ip
            f.write(struct.pack("<IIII", int(s), round(s % 1 * 1e6), len(eth), len(eth)) + eth)
    return path


def velodyne32_stream(factory: int, *, dual: bool = False, n_sweeps: float = 1.3, unit: float = 0.004):
    """Data packets of a 32-laser Velodyne (one firing per block; ``dual``: blocks in pairs, last
    return then strongest, the last 2 m behind on every third laser) in a round room."""
    deg_per_s = 3600.0
    firings = int(n_sweeps * 0.1 / FIRING_32) // 12 * 12
    per_packet = 6 if dual else 12
    payloads, stamps = [], []
    for p0 in range(0, firings, per_packet):
        buf = bytearray()
        for j in range(p0, p0 + per_packet):
            az = (j * FIRING_32 * deg_per_s + 10.0) % 360.0
            r = 10.0 + 2.0 * np.sin(np.radians(az) * 3)
            for last in (True, False) if dual else (False,):
                buf += b"\xff\xee" + struct.pack("<H", round(az * 100) % 36000)
                for k in range(32):
                    rk = r + 2.0 if last and k % 3 == 0 else r
                    buf += struct.pack("<HB", int(rk / unit), 50 if last else 100)
        buf += struct.pack("<IBB", int(p0 * FIRING_32 * 1e6), 0x39 if dual else 0x37, factory)
        payloads.append(bytes(buf))
        stamps.append(1.0e9 + p0 * FIRING_32)
    return payloads, stamps


FIRING_32 = 55.296e-6  # s per firing of the 32-laser models (one block)
