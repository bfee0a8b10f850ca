"""Ouster captures as they come off a network: a sensor on another UDP port than its json says is
an error naming the ports; other traffic and pcapng read the same sweeps.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from tests.inputs.captures import eth_udp, write_frames_pcap, write_pcapng


def pcap_records(path: Path) -> tuple[int, list[tuple[float, bytes]]]:
    """Link type and (stamp, frame) records of a little-endian microsecond pcap."""
    raw = path.read_bytes()
    assert struct.unpack("<I", raw[:4])[0] == 0xA1B2C3D4
    link, k, out = struct.unpack("<I", raw[20:24])[0], 24, []
    while k + 16 <= len(raw):
        sec, us, incl, _ = struct.unpack("<IIII", raw[k : k + 16])
        out.append((sec + us * 1e-6, raw[k + 16 : k + 16 + incl]))
        k += 16 + incl
    return link, out


def with_ports(frame: bytes, port: int) -> bytes:
    """The Ethernet/IPv4/UDP frame sent from and to ``port``."""
    b = bytearray(frame)
    struct.pack_into(">HH", b, 14 + (b[14] & 0x0F) * 4, port, port)
    return bytes(b)


@pytest.fixture(scope="module")
def ouster_capture() -> tuple[Path, Path]:
    from tests.conftest import SHARED_DATA

    pcap = SHARED_DATA / "ouster" / "pcaps" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
    meta = pcap.with_name("OS-1-128_v2.3.0_1024x10.json")
    if not pcap.is_file() or not meta.is_file():
        pytest.skip(f"Ouster capture not found: {pcap}")
    return pcap, meta


def test_ouster_capture_on_another_port_names_the_ports(ouster_capture, tmp_path):
    """A sensor configured to another UDP port than its json says: the error gives the json's port and the
    capture's ports and packet sizes."""
    pcap, meta = ouster_capture
    _, recs = pcap_records(pcap)
    path = write_frames_pcap(tmp_path / "moved.pcap", [(s, with_ports(f, 7777)) for s, f in recs])
    with pytest.raises(DataError) as exc:
        open_dataset(path, "ouster-pcap", meta=meta)
    msg = str(exc.value)
    assert "\n" not in msg and "udp_port_lidar 7502" in msg and "port 7777: 192 of 8448 bytes" in msg


def test_ouster_capture_with_other_traffic_and_as_pcapng_reads_the_same_sweeps(ouster_capture, tmp_path):
    """Packets of the lidar's size on another port (a second application, mirrored traffic) are
    not lidar packets; pcapng reads as pcap."""
    pcap, meta = ouster_capture
    ref = open_dataset(pcap, "ouster-pcap", meta=meta)
    _, recs = pcap_records(pcap)
    rng = np.random.default_rng(1)
    junk = [(s + 1e-6, eth_udp(rng.bytes(8448), 7600)) for s, _ in recs[::3]]
    mirrored = [(s + 2e-6, with_ports(f, 7777)) for s, f in recs]
    busy = write_frames_pcap(tmp_path / "busy.pcap", sorted(recs + junk + mirrored, key=lambda x: x[0]))
    ng = write_pcapng(tmp_path / "ng.pcapng", recs)
    for path in (busy, ng):
        ds = open_dataset(path, "ouster-pcap", meta=meta)
        assert len(ds) == len(ref) == 3
        np.testing.assert_array_equal(ds.frame_ids, ref.frame_ids)
        for i in range(len(ref)):
            np.testing.assert_array_equal(ds[i].ranges, ref[i].ranges)
