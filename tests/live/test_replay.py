"""``prc-slam replay``: a capture's main stream sent over loopback with its recorded spacing."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest

from prc_slam.live.replay import main_port, parse_target, replay
from tests.conftest import SHARED_DATA
from tests.inputs.velodyne import vlp16_stream, write_pcap

LOOPBACK = "127.0.0.1"


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    payloads, stamps = vlp16_stream(n_sweeps=0.5)[:2]
    path = tmp_path_factory.mktemp("replay") / "c.pcap"
    return write_pcap(path, payloads, stamps)


def receive_all(port_holder: list, sock: socket.socket) -> list[tuple[float, bytes]]:
    got = []
    sock.settimeout(1.0)
    try:
        while True:
            data = sock.recv(65535)
            got.append((time.perf_counter(), data))
    except TimeoutError:
        pass
    return got


def listener() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 2**20)
    s.bind((LOOPBACK, 0))
    return s


def test_target_parsed():
    assert parse_target("udp://127.0.0.1:2368", None) == ("127.0.0.1", 2368)
    assert parse_target("udp://127.0.0.1", None) == ("127.0.0.1", None)
    with pytest.raises(ValueError, match="--to"):
        parse_target("tcp://127.0.0.1:1", None)
    with pytest.raises(ValueError, match="out of range"):
        parse_target("udp://127.0.0.1:70000", None)


def test_replay_sends_every_packet_with_its_spacing(capture):
    from data_tools.formats.velodyne_pcap import Capture

    packets = [p for _t, _s, p in Capture(capture)]
    stamps = [t for t, _s, _p in Capture(capture)]
    with listener() as sock:
        stats = replay(capture, LOOPBACK, sock.getsockname()[1], loop=2)
        got = receive_all([], sock)
    assert stats.sent == len(got) == 2 * len(packets)
    assert [p for _t, p in got[: len(packets)]] == packets
    span = stamps[-1] - stamps[0]
    assert stats.seconds >= 2 * span * 0.9  # the recorded spacing kept (never faster)


def test_replay_rate_and_seeded_drops(capture):
    with listener() as sock:
        a = replay(capture, LOOPBACK, sock.getsockname()[1], rate=4.0, drop=0.2, seed=1)
        got = receive_all([], sock)
    b = replay(capture, LOOPBACK, 9, rate=100.0, drop=0.2, seed=1)  # (port 9: discard)
    assert a.dropped == b.dropped > 0 and a.sent == len(got) == b.sent


def test_ouster_capture_main_stream_is_its_lidar_port():
    pcaps = sorted(SHARED_DATA.joinpath("ouster", "pcaps").glob("*.pcap"))
    if not pcaps:
        pytest.skip("shared Ouster captures not found")
    assert main_port(pcaps[0]) == 7502
