"""The Rerun sink: record a short simulated run, read it back with rerun.chunk.RrdReader."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun.chunk as rc

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import NoiseConfig, SimConfig, Simulator
from prc_slam.config import Config, PRCConfig
from prc_slam.odometry.compare import run_compare
from prc_slam.online import OnlineDetector
from prc_slam.viz.sink import RerunSink, VizConfig, open_recording

FRAMES = 6


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("viz")
    seq = open_dataset(
        write_sequence(Simulator(SimConfig(frames=FRAMES, seed=2, noise=NoiseConfig(outlier_rate=0.01))), tmp / "sim")
    )
    rrd = tmp / "run.rrd"
    rec, _ = open_recording(rrd=str(rrd))
    sink = RerunSink(rec, VizConfig(every=1, map_every=1))
    detector = OnlineDetector()
    expected = []

    def on_frame(record):
        scan = record.frame.scan
        sink.log_record(record, gt_pose=scan.gt_pose)
        online = detector.process(scan)
        sink.log_online(record.index, scan, online, scan.gt_pose)
        expected.append(
            {
                "labels": record.frame.point_labels().copy(),
                "kept": record.kept["prc"].copy(),
                "n": scan.n_points,
                "online": scan.per_point(online.labels),
                "cars": len(online.car_boxes),
                "curbs": len(online.curb_polylines),
            }
        )

    run_compare(iter(seq), Config(prc=PRCConfig.preset("multibeam")), on_frame=on_frame)
    sink.warn("a warning")
    rec.flush()
    rec.disconnect()
    return rrd, expected


def rows_by_frame(rrd: Path, entity: str, column: str) -> dict[int, object]:
    out = {}
    for chunk in rc.RrdReader(str(rrd)).store().stream():
        if chunk.entity_path != entity:
            continue
        rb = chunk.to_record_batch()
        if column not in rb.schema.names:
            continue
        frames = rb.column("frame").to_pylist() if "frame" in rb.schema.names else [None] * rb.num_rows
        for f, value in zip(frames, rb.column(column).to_pylist(), strict=True):
            out[f] = value
    return out


def test_every_entity_is_recorded(recorded):
    rrd, _ = recorded
    paths = {c.entity_path for c in rc.RrdReader(str(rrd)).store().stream()}
    for p in (
        "/",
        "/world/sensor",
        "/world/sensor/raw",
        "/world/sensor/filtered",
        "/world/map",
        "/world/trajectory/estimate",
        "/world/trajectory/ground_truth",
        "/world/trajectory/variants/raw",
        "/world/trajectory/variants/prc",
        "/range_image/range",
        "/range_image/prc",
        "/logs",
        "/metrics/ms/prc/prc",
        "/metrics/icp_threshold/prc",
        "/metrics/points/ground/kept",
        "/metrics/error/position_m",
        "/world/detections/cars",
        "/world/detections/curbs",
        "/world/sensor/online",
        "/range_image/online",
    ):
        assert p in paths, p


def test_point_counts_and_class_ids_match_the_run(recorded):
    rrd, expected = recorded
    raw_pos = rows_by_frame(rrd, "/world/sensor/raw", "Points3D:positions")
    raw_ids = rows_by_frame(rrd, "/world/sensor/raw", "Points3D:class_ids")
    filt = rows_by_frame(rrd, "/world/sensor/filtered", "Points3D:positions")
    filt_ids = rows_by_frame(rrd, "/world/sensor/filtered", "Points3D:class_ids")
    assert sorted(raw_pos) == list(range(FRAMES))
    for i, exp in enumerate(expected):
        assert len(raw_pos[i]) == exp["n"]
        np.testing.assert_array_equal(raw_ids[i], exp["labels"])
        assert len(filt[i]) == int(exp["kept"].sum())
        np.testing.assert_array_equal(filt_ids[i], exp["labels"][exp["kept"]])


def test_detector_labels_boxes_and_curbs_match_the_run(recorded):
    rrd, expected = recorded
    ids = rows_by_frame(rrd, "/world/sensor/online", "Points3D:class_ids")
    boxes = rows_by_frame(rrd, "/world/detections/cars", "Boxes3D:half_sizes")
    curbs = rows_by_frame(rrd, "/world/detections/curbs", "LineStrips3D:strips")
    for i, exp in enumerate(expected):
        np.testing.assert_array_equal(ids[i], exp["online"])
        assert len(boxes.get(i) or []) == exp["cars"]
        assert len(curbs.get(i) or []) == exp["curbs"]
    assert any(exp["cars"] for exp in expected) and any(exp["curbs"] for exp in expected)


def test_trajectory_has_one_pose_per_frame(recorded):
    rrd, _ = recorded
    strips = rows_by_frame(rrd, "/world/trajectory/estimate", "LineStrips3D:strips")
    gt = rows_by_frame(rrd, "/world/trajectory/ground_truth", "LineStrips3D:strips")
    poses = rows_by_frame(rrd, "/world/sensor", "Transform3D:translation")
    for i in range(FRAMES):
        assert len(strips[i][0]) == i + 1 and len(gt[i][0]) == i + 1
    assert len(poses) == FRAMES
    np.testing.assert_allclose(np.ravel(poses[FRAMES - 1]), strips[FRAMES - 1][0][-1], atol=1e-5)


def test_rerun_verifies_the_file(recorded):
    rrd, _ = recorded
    cli = Path(sys.executable).with_name("rerun")
    res = subprocess.run([str(cli), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "verified without error" in res.stdout + res.stderr


def _rerun_cli() -> str:
    return str(Path(sys.executable).with_name("rerun"))


def _prc_slam_cli() -> str:
    return str(Path(sys.executable).with_name("prc-slam"))


def _sim(tmp: Path) -> Path:
    return write_sequence(Simulator(SimConfig(frames=3, seed=4)), tmp / "sim")


def test_serve_web_serves_the_viewer_and_the_stream(tmp_path):
    import time
    import urllib.request

    proc = subprocess.Popen(
        [
            _prc_slam_cli(),
            "compare",
            str(_sim(tmp_path)),
            "--out",
            str(tmp_path / "out"),
            "--serve-web",
            "--serve-seconds",
            "40",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        address = None
        deadline = time.monotonic() + 60
        while address is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if "web viewer:" in line:
                address = line.split("web viewer:", 1)[1].strip()
        assert address and address.startswith("http://localhost:9090/"), address
        with urllib.request.urlopen("http://localhost:9090/", timeout=10) as page:
            assert page.status == 200
            assert "Rerun" in page.read().decode("utf-8", "replace")
        recv = subprocess.run(
            [_rerun_cli(), "--headless", "--test-receive", "--connect", "rerun+http://127.0.0.1:9876/proxy"],
            capture_output=True,
            text=True,
            timeout=90,
        )
        assert recv.returncode == 0, recv.stdout + recv.stderr
        assert "Received first message" in recv.stdout + recv.stderr
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def _free_port() -> int:
    """A local port nothing listens on (bound, then closed again)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _compare_connected(tmp_path, port: int, timeout: float) -> subprocess.CompletedProcess:
    """``prc-slam compare`` on a small simulation, streaming to the viewer at ``port``."""
    return subprocess.run(
        [
            _prc_slam_cli(),
            "compare",
            str(_sim(tmp_path)),
            "--out",
            str(tmp_path / "out"),
            "--connect",
            f"rerun+http://127.0.0.1:{port}/proxy",
        ],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_connect_streams_to_a_running_viewer(tmp_path):
    import socket
    import time

    port = _free_port()
    receiver = subprocess.Popen(
        [_rerun_cli(), "--headless", "--test-receive", "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60  # the viewer listening (slow to start on a busy machine)
        while time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.2)
        run = _compare_connected(tmp_path, port, timeout=120)
        assert run.returncode == 0, run.stdout + run.stderr
        out, _ = receiver.communicate(timeout=60)
        assert receiver.returncode == 0, out
        assert "Received first message" in out
    finally:
        if receiver.poll() is None:
            receiver.kill()


def test_viewer_that_never_answers_costs_only_the_recording(tmp_path):
    """--connect to a port where no viewer listens: the run completes and writes its outputs,
    with one warning that the recording was not delivered (no traceback)."""
    run = _compare_connected(tmp_path, _free_port(), timeout=180)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "the recording could not be delivered" in run.stdout + run.stderr
    assert "Traceback" not in run.stdout + run.stderr
    assert (tmp_path / "out" / "metrics.json").is_file() and (tmp_path / "out" / "report.md").is_file()


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (512_345.678, 5_412_345.321, 312.5)])
def test_classified_map_far_from_the_origin_keeps_its_millimetres(tmp_path, offset):
    """Rerun stores float32 positions (0.5 m apart at a UTM northing): a geo-referenced map is
    logged relative to a display origin, said in the text log, and adding it back gives the
    points to a millimetre; a map near the origin is logged as it is."""
    rng = np.random.default_rng(0)
    local = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0), [0.0, 1.0]), -1).reshape(-1, 3)
    local += rng.uniform(-0.3, 0.3, local.shape)  # 1 m apart: none thinned away
    pts = local + np.asarray(offset)
    rrd = tmp_path / "map.rrd"
    rec, _ = open_recording(rrd=str(rrd))
    sink = RerunSink(rec, VizConfig(map_voxel=0.1))
    sink.log_map(pts[:400], np.full(400, 1, np.uint8), part=0)
    sink.log_map(pts[400:], np.full(len(pts) - 400, 2, np.uint8), part=1)
    rec.flush()
    rec.disconnect()
    got = [np.array(rows_by_frame(rrd, f"/world/map_classified/part_{k}", "Points3D:positions")[None]) for k in (0, 1)]
    got = np.concatenate([np.array(g, dtype=np.float64) for g in got]) + sink.map_origin
    assert got.shape == pts.shape
    np.testing.assert_allclose(np.sort(got, axis=0), np.sort(pts, axis=0), atol=1e-3)
    logs = " ".join(str(v) for v in rows_by_frame(rrd, "/logs", "TextLog:text").values())
    if offset[0]:
        assert np.all(np.abs(pts - sink.map_origin).max(axis=0) < 1e3)
        # the first chunk's median (x 9.5 m and y 4.5 m into the grid), rounded to 100 m
        assert "shifted by (-512400, -5412300, -300) m" in logs
    else:
        assert not sink.map_origin.any() and "shifted" not in logs
