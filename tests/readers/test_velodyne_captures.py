"""Velodyne captures as they come off a network (simulated VLP-16 data packets): pcapng and other link
types, other traffic, two sensors in one capture, stray packets, truncated and foreign captures, and
recordings of raw Velodyne packets (ROS 1 and 2).
"""

from __future__ import annotations

import logging
import struct

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.datasets import detect_format
from tests.inputs.captures import eth_udp, write_frames_pcap, write_pcapng
from tests.inputs.rosbags import velodyne_scan_bag
from tests.inputs.velodyne import vlp16_stream


@pytest.fixture(scope="module")
def vlp16_frames() -> list[tuple[float, bytes]]:
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.3)
    return [(s, eth_udp(p, 2368)) for p, s in zip(payloads, stamps, strict=True)]


@pytest.fixture(scope="module")
def reference(vlp16_frames, tmp_path_factory) -> tuple[np.ndarray, list[np.ndarray]]:
    """Sweep stamps and points of the plain capture."""
    ds = open_dataset(write_frames_pcap(tmp_path_factory.mktemp("ref") / "ref.pcap", vlp16_frames))
    return ds.times, [ds.sweep(i)[1] for i in range(len(ds))]


def same_sweeps(ds, reference) -> None:
    times, sweeps = reference
    assert ds.format == "velodyne-pcap" and len(ds) == len(sweeps)
    np.testing.assert_allclose(ds.times, times, rtol=0, atol=2e-6)
    for i, ref in enumerate(sweeps):
        got = ds.sweep(i)[1]
        assert len(got) == len(ref)
        for c in ("x", "y", "z", "ring"):
            np.testing.assert_array_equal(got[c], ref[c])


def gprmc_packet(t: float) -> bytes:
    """A VLP-16 position packet (512 bytes, NMEA GPRMC at byte 206), sent to port 8308."""
    buf = bytearray(512)
    struct.pack_into("<I", buf, 198, int((t % 3600) * 1e6))
    nmea = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n"
    buf[206 : 206 + len(nmea)] = nmea
    return bytes(buf)


@pytest.mark.parametrize("case", ["pcapng", "pcapng_ns", "pcapng_named_pcap", "nano", "bigendian"])
def test_capture_file_formats_decode_the_same_sweeps(case, vlp16_frames, reference, tmp_path):
    """pcapng (micro- or nanosecond stamps, even named .pcap), nanosecond-magic and big-endian
    pcap: the same sweeps as the plain capture."""
    if case.startswith("pcapng"):
        suffix = ".pcap" if case == "pcapng_named_pcap" else ".pcapng"
        path = write_pcapng(tmp_path / f"v{suffix}", vlp16_frames, tsresol=9 if case == "pcapng_ns" else None)
    else:
        path = write_frames_pcap(tmp_path / "v.pcap", vlp16_frames, nano=case == "nano", big=case == "bigendian")
    assert detect_format(path) == "velodyne-pcap"
    same_sweeps(open_dataset(path), reference)


LINK_HEADERS = {  # link type -> header put before the IPv4 packet of an Ethernet frame
    "ethernet_vlan": (1, b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x01" + b"\x81\x00\x00\x05" + b"\x08\x00"),
    "linux_sll": (113, b"\x00\x00\x00\x01\x00\x06" + b"\x60\x76\x88\x00\x00\x01\x00\x00" + b"\x08\x00"),
    "linux_sll2": (
        276,
        b"\x08\x00\x00\x00" + b"\x00\x00\x00\x02" + b"\x00\x01\x00\x06" + b"\x60\x76\x88\x00\x00\x01\x00\x00",
    ),
    "raw_ip": (101, b""),
}


@pytest.mark.parametrize("link", sorted(LINK_HEADERS))
def test_captures_of_other_link_types_decode_the_same_sweeps(link, vlp16_frames, reference, tmp_path):
    """``tcpdump -i any`` writes Linux cooked frames (v2 on current libpcap); VLAN-tagged Ethernet and raw IP
    captures decode the same sweeps as Ethernet ones."""
    code, header = LINK_HEADERS[link]
    path = write_frames_pcap(tmp_path / "v.pcap", [(s, header + eth[14:]) for s, eth in vlp16_frames], link=code)
    same_sweeps(open_dataset(path), reference)


def test_other_traffic_is_skipped(vlp16_frames, reference, tmp_path):
    """Position packets on 8308, 300 packets of other UDP traffic before the lidar starts, 1206-byte
    datagrams that are not Velodyne data on another port, TCP and ARP frames: the lidar's sweeps only."""
    rng = np.random.default_rng(0)
    t0 = vlp16_frames[0][0]
    other = [(t0 - 1 + k * 1e-3, eth_udp(rng.bytes(300), 5353)) for k in range(300)]
    other += [(s + 1e-4, eth_udp(gprmc_packet(s), 8308)) for s, _ in vlp16_frames[::40]]
    other += [(s + 5e-5, eth_udp(rng.bytes(1206), 9999)) for s, _ in vlp16_frames[::10]]
    other += [(s + 3e-5, eth_udp(b"\x00" * 40, 0, proto=6)) for s, _ in vlp16_frames[::5]]
    arp = b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x02\x08\x06" + b"\x00" * 28
    other += [(s + 4e-5, arp) for s, _ in vlp16_frames[::7]]
    path = write_frames_pcap(tmp_path / "busy.pcap", sorted(vlp16_frames + other, key=lambda x: x[0]))
    assert detect_format(path) == "velodyne-pcap"
    same_sweeps(open_dataset(path), reference)


def test_two_velodyne_sensors_in_one_capture_are_an_error_naming_both(vlp16_frames, tmp_path):
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.3, seed=5)
    second = [(s + 2e-5, eth_udp(p, 2369, src=(192, 168, 1, 202))) for p, s in zip(payloads, stamps, strict=True)]
    path = write_frames_pcap(tmp_path / "two.pcap", sorted(vlp16_frames + second, key=lambda x: x[0]))
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg
    assert "192.168.1.201 -> port 2368" in msg and "192.168.1.202 -> port 2369" in msg


def test_a_few_stray_packets_of_another_sensor_are_dropped_with_a_warning(vlp16_frames, reference, tmp_path, caplog):
    stray = [(s + 2e-5, eth_udp(eth[42:], 2368, src=(10, 0, 0, 9))) for s, eth in vlp16_frames[:3]]  # 42: headers
    path = write_frames_pcap(tmp_path / "stray.pcap", sorted(vlp16_frames + stray, key=lambda x: x[0]))
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(path)
    assert any("3 Velodyne data packets from other sources" in r.getMessage() for r in caplog.records)
    same_sweeps(ds, reference)


@pytest.mark.parametrize("cut", [500, 1206 + 42 + 8], ids=["inside_data", "inside_record_header"])
def test_a_truncated_capture_keeps_the_sweeps_before_the_cut(cut, vlp16_frames, reference, tmp_path, caplog):
    full = write_frames_pcap(tmp_path / "full.pcap", vlp16_frames)
    path = tmp_path / "cut.pcap"
    path.write_bytes(full.read_bytes()[:-cut])
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(path)
    assert any("truncated" in r.getMessage() for r in caplog.records)
    _, sweeps = reference
    assert len(ds) == len(sweeps)
    for i in range(len(ds) - 1):  # whole sweeps as before; the last one loses the cut packet only
        np.testing.assert_array_equal(ds.sweep(i)[1]["x"], sweeps[i]["x"])
    assert 0 < len(sweeps[-1]) - len(ds.sweep(len(ds) - 1)[1]) <= 384


def test_a_capture_without_velodyne_packets_is_a_one_line_error(tmp_path):
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    from data_tools.formats.velodyne_pcap import VelodynePcapSequence

    path = write_frames_pcap(tmp_path / "gps.pcap", [(1e9 + k, eth_udp(gprmc_packet(k), 8308)) for k in range(5)])
    with pytest.raises(DataError, match="no Velodyne data packets") as exc:
        VelodynePcapSequence(path)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)
    bad = tmp_path / "notacapture.pcap"
    bad.write_bytes(b"hello world, this is not a capture at all")
    with pytest.raises(DataError, match="not a pcap or pcapng") as exc:
        VelodynePcapSequence(bad)


@pytest.mark.parametrize("content, message", [(b"", "empty file"), (b"hello\n", "not a pcap or pcapng capture")])
def test_an_empty_or_foreign_pcap_says_so(tmp_path, content, message):
    """It said 'no Ouster sensor metadata: expected ...json beside it'."""
    path = tmp_path / "x.pcap"
    path.write_bytes(content)
    with pytest.raises(DataError, match=message) as exc:
        open_dataset(path)
    assert "Ouster" not in str(exc.value) and str(path) in str(exc.value)


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_a_recording_of_raw_velodyne_packets_is_decoded_like_the_capture(kind, vlp16_frames, reference, tmp_path):
    """A bag recorded from ``/velodyne_packets`` (velodyne_msgs/VelodyneScan, common in public datasets) is
    decoded like the capture of the same packets."""
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.3)
    name = "packets.bag" if kind == "ros1" else "packets"
    path = velodyne_scan_bag(tmp_path / name, kind, payloads, stamps, "/velodyne_packets")
    ds = open_dataset(path)
    assert ds.model == "VLP16" and ds.topic == "/velodyne_packets"
    same_sweeps(ds, reference)
    scan = ds[0]
    assert scan.meta["organize"]["rings"] == 16 and scan.n_points == len(reference[1][0])


def test_two_velodyne_packet_topics_need_a_topic(tmp_path):
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, _ = vlp16_stream(n_sweeps=0.3)
    path = velodyne_scan_bag(tmp_path / "a.bag", "ros1", payloads, stamps, "/front/velodyne_packets")
    both = tmp_path / "both"  # a folder of split bags, one topic each
    both.mkdir()
    velodyne_scan_bag(both / "1.bag", "ros1", payloads, stamps, "/front/velodyne_packets")
    velodyne_scan_bag(both / "2.bag", "ros1", payloads, stamps, "/rear/velodyne_packets")
    with pytest.raises(DataError, match="2 VelodyneScan topics, choose one with --topic") as exc:
        open_dataset(both)
    assert "/front/velodyne_packets" in str(exc.value) and "/rear/velodyne_packets" in str(exc.value)
    assert len(open_dataset(both, topic="/rear/velodyne_packets")) >= 1
    assert open_dataset(path).topic == "/front/velodyne_packets"
