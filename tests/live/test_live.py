"""``prc-slam live``: a replayed capture on loopback gives the offline poses; faults are counted,
warned and survived; every output is valid when the run stops."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from prc_slam.live.receiver import LiveError, Sweep, SweepQueue
from prc_slam.live.replay import replay
from prc_slam.live.run import LiveOptions, run_live
from prc_slam.live.sources import Source, parse_source
from tests.conftest import SHARED_DATA

LOOPBACK = "127.0.0.1"


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """A simulated VLP-16 drive of 6 sweeps as a Velodyne capture."""
    from data_tools.formats.velodyne_packets import SimCapture
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path_factory.mktemp("live")
    sim = Simulator(SimConfig(sensor="vlp16", frames=6, clockwise=True, speed=1.3))
    cap = SimCapture(root / "cap.pcap", sim.sensor, "vlp16")
    write_sequence(sim, root / "seq", on_frame=cap.add)
    cap.close()
    return root / "cap.pcap"


def config():
    from prc_slam.cli.common import Preset, run_config

    return run_config(Preset.multibeam, None)


def live_over_replay(capture: Path, tmp_path: Path, *, replay_kw=None, during=None, kill_after=None, **opts):
    """``run_live`` on a free loopback port while ``capture`` is replayed into it by a second
    process, started ahead and told the port once the receiver listens (``during(rx)`` runs
    beside on a thread, e.g. to send other datagrams; ``kill_after``: the replaying process is
    killed after that many seconds). Returns (LiveRun, replay stats, None when killed)."""
    import multiprocessing as mp

    from prc_slam.live.replay import replay_when_told

    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=replay_when_told, args=(capture, child, replay_kw or {}), daemon=True)
    proc.start()
    threads: list[threading.Thread] = []

    def on_ready(rx):
        parent.send(rx.port)
        if kill_after is not None:
            threading.Timer(kill_after, proc.kill).start()
        if during is not None:
            threads.append(threading.Thread(target=during, args=(rx,), daemon=True))
            threads[-1].start()

    opts.setdefault("warm_up", False)  # (latency is not what these tests check)
    options = LiveOptions(timeout=opts.pop("timeout", 1.0), queue=opts.pop("queue", 1000), **opts)
    try:
        run = run_live(
            Source("velodyne", LOOPBACK, 0), config(), options, poses_out=tmp_path / "poses.txt", on_ready=on_ready
        )
    finally:
        for t in threads:
            t.join(timeout=10)
        proc.join(timeout=10)
        if proc.is_alive():
            proc.kill()
            proc.join()
    return run, (parent.recv() if parent.poll(0.5) else None)


def test_queue_drops_the_oldest_whole_sweep():
    q = SweepQueue(2)
    for i in range(5):
        q.put(Sweep(i, 0.0))
    assert q.dropped == 3
    assert [q.get(0.01).index, q.get(0.01).index] == [3, 4]
    assert q.get(0.01) is None


def test_sources_parsed():
    assert parse_source("velodyne://127.0.0.1") == Source("velodyne", "127.0.0.1", 2368)
    assert parse_source("ouster://127.0.0.1:7000") == Source("ouster", "127.0.0.1", 7000)
    with pytest.raises(ValueError, match="unknown scheme"):
        parse_source("hesai://127.0.0.1")
    with pytest.raises(ValueError, match="port"):
        parse_source("velodyne://127.0.0.1:x")


def test_live_poses_equal_offline(capture, tmp_path):
    """Same sweeps, same organisation, same stages: the offline poses to 1e-6 m."""
    from prc_slam.jobs.odometry import run_odometry

    run, sent = live_over_replay(capture, tmp_path)
    m = run.metrics
    offline, _ = run_odometry(capture, config(), ["prc"])
    want = offline.result.estimate_in_world("prc")
    got = run.result.odometry.estimate_in_world("prc")
    assert sent.sent == 6 * 75
    assert m["frames"] == len(want) == len(got) == 6, m.get("variants", {}).get("prc", {}).get("failure_reason")
    assert m["dropped_frames"] == 0 and m["lost_packets"] == 0 and m["foreign_packets"] == 0
    assert np.abs(got[:, :3, 3] - want[:, :3, 3]).max() <= 1e-6
    assert m["latency_ms"]["p50"] is not None and m["ended_by"] == "timeout"
    assert {"prc", "icp", "sinks"} <= set(m["ms_per_stage"])
    assert len((tmp_path / "poses.txt").read_text().splitlines()) == 6


def test_lost_packets_counted_and_sweeps_processed(capture, tmp_path):
    run, sent = live_over_replay(capture, tmp_path, replay_kw={"drop": 0.05, "seed": 3})
    m = run.metrics
    assert sent.dropped > 0
    # a gap is seen between two packets received: all but drops at the very start or end
    assert 0 < m["lost_packets"] <= sent.dropped
    assert m["frames"] >= 5 and m["frames_with_lost_packets"] >= 1


def test_garbage_datagrams_skipped_and_counted(capture, tmp_path):
    def garbage(rx):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for n in (1, 17, 1206, 1500):
                s.sendto(os.urandom(n) if n != 1206 else b"\x00" * 1206, (LOOPBACK, rx.port))
                time.sleep(0.05)

    run, _ = live_over_replay(capture, tmp_path, during=garbage)
    assert run.metrics["foreign_packets"] == 4
    assert run.metrics["frames"] == 6


def test_second_sensor_on_the_port_is_an_error(capture, tmp_path):
    def second(rx):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            from data_tools.formats.velodyne_pcap import Capture

            for k, (_t, _src, payload) in enumerate(Capture(capture)):
                if k >= 40:
                    break
                s.sendto(payload, (LOOPBACK, rx.port))
                time.sleep(0.002)

    with pytest.raises(LiveError, match=r"two sensors on port \d+: 127\.0\.0\.1:\d+ and 127\.0\.0\.1:\d+"):
        live_over_replay(capture, tmp_path, during=second)
    assert (tmp_path / "poses.txt").exists()  # closed, whatever it holds


def test_sender_killed_warns_then_timeout_ends_with_valid_outputs(capture, tmp_path):
    run, sent = live_over_replay(capture, tmp_path, replay_kw={"rate": 0.25}, kill_after=1.0, timeout=2.5)
    m = run.metrics
    assert sent is None  # killed before it finished
    assert m["ended_by"] == "timeout"
    assert any("no packets for 2 s" in w for w in m["warnings"])
    assert 1 <= m["frames"] < 6 and m["frames"] == m["sweeps_in"]
    lines = (tmp_path / "poses.txt").read_text().splitlines()
    assert len(lines) == m["frames"] and all(len(x.split()) == 8 for x in lines)


def test_realtime_recording_as_a_sensor(capture, tmp_path):
    src = parse_source(str(capture.parent / "seq"))
    run = run_live(src, config(), LiveOptions(queue=100, warm_up=False), poses_out=tmp_path / "p.txt")
    m = run.metrics
    assert m["frames"] == 6 and m["ended_by"] == "end of recording"
    assert m["rate_hz_in"] == pytest.approx(10.0, rel=0.5)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def test_sigterm_stops_and_closes_every_output(capture, tmp_path):
    """The CLI: SIGTERM mid-stream → the run ends normally, the .rrd, MCAP, poses and JSON valid."""
    port = free_port()
    exe = Path(sys.executable).with_name("prc-slam")
    cmd = [str(exe), "live", f"velodyne://{LOOPBACK}:{port}", "--json", str(tmp_path / "m.json"),
           "--rrd", str(tmp_path / "r.rrd"), "--out", str(tmp_path / "f.mcap"), "--poses-out", str(tmp_path / "p.txt"),
           "--timeout", "30", "--queue", "100"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if "listening" in line or not line:
                break
        replay(capture, LOOPBACK, port)
        time.sleep(1.0)
        children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children")
        kids = children.read_text().split() if children.exists() else []
        proc.send_signal(signal.SIGTERM)
        text, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, text
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and any(Path(f"/proc/{k}").exists() for k in kids):
        time.sleep(0.1)
    left = [Path(f"/proc/{k}/cmdline").read_bytes()[:80] for k in kids if Path(f"/proc/{k}").exists()]
    assert not left  # the receiving process (and multiprocessing's tracker) ended too
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["ended_by"] == "stopped" and m["frames"] == m["sweeps_in"] >= 5
    assert (tmp_path / "r.rrd").stat().st_size > 0 and not (tmp_path / "r.partial.rrd").exists()
    from data_tools import open_dataset

    filtered = open_dataset(tmp_path / "f.mcap")
    assert len(filtered) == m["frames"]
    assert max(len(filtered[i].points()) for i in range(len(filtered))) > 1000
    assert len((tmp_path / "p.txt").read_text().splitlines()) == m["frames"]


OUSTER = SHARED_DATA / "ouster" / "pcaps"


def test_ouster_packets_labelled_as_offline(tmp_path):
    """A shared Ouster capture replayed twice into ouster://: each sweep's PRC labels are those of
    the offline reading of the capture."""
    from data_tools.formats.ouster_pcap import OusterPcapSequence
    from prc_slam.jobs.sinks import LabelFiles
    from prc_slam.pipeline import Pipeline

    pcap = OUSTER / "OS-0-128-U1_v2.3.0_1024x10.pcap"
    if not pcap.is_file():
        pytest.skip(f"shared Ouster capture not found: {pcap}")
    meta = pcap.with_suffix(".json")
    Pipeline(prc=config().prc, sinks=[LabelFiles(tmp_path / "offline")]).run(iter(OusterPcapSequence(pcap)))
    threads = []

    def on_ready(rx):
        threads.append(threading.Thread(target=replay, args=(pcap, LOOPBACK, rx.port), kwargs={"loop": 2}))
        threads[0].start()

    try:
        run = run_live(
            Source("ouster", LOOPBACK, 0), config(), LiveOptions(timeout=1.5, queue=100, meta=meta, warm_up=False),
            labels_out=tmp_path / "live", on_ready=on_ready,
        )  # fmt: skip
    finally:
        for t in threads:
            t.join(timeout=10)
    assert run.metrics["frames"] == 2 and run.metrics["lost_packets"] == 0
    want = np.fromfile(tmp_path / "offline" / "000000.label", np.uint32)
    for name in ("000000.label", "000001.label"):
        assert np.array_equal(np.fromfile(tmp_path / "live" / name, np.uint32), want)


@pytest.mark.parametrize(
    "args, message",
    [
        (["hesai://127.0.0.1"], "unknown scheme 'hesai'"),
        (["velodyne://127.0.0.1:99999"], "port 99999 out of range"),
        (["ouster://127.0.0.1"], "--meta"),
        (["velodyne://127.0.0.1:9", "--out", "x.bag"], "--out x.bag"),
        (["no-such-recording"], "no such file"),
    ],
)
def test_cli_errors_are_one_line(args, message):
    from typer.testing import CliRunner

    from prc_slam.cli import app

    res = CliRunner().invoke(app, ["live", *args])
    assert res.exit_code == 2
    assert message in res.output and "Traceback" not in res.output


def test_port_in_use_is_named():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        port = s.getsockname()[1]
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{port}"):
            run_live(Source("velodyne", LOOPBACK, port), config(), LiveOptions(timeout=0.5, warm_up=False))


def test_ouster_lost_packets_counted(tmp_path):
    pcap = OUSTER / "OS-0-128-U1_v2.3.0_1024x10.pcap"
    if not pcap.is_file():
        pytest.skip(f"shared Ouster capture not found: {pcap}")
    sent: list = []

    def on_ready(rx):
        def play():
            sent.append(replay(pcap, LOOPBACK, rx.port, loop=3, drop=0.1, seed=4))

        threading.Thread(target=play, daemon=True).start()

    opts = LiveOptions(timeout=1.0, queue=100, meta=pcap.with_suffix(".json"), warm_up=False)
    run = run_live(Source("ouster", LOOPBACK, 0), config(), opts, on_ready=on_ready)
    m = run.metrics
    assert sent and sent[0].dropped > 0
    assert m["frames"] == 3 and m["lost_packets"] == sent[0].dropped
