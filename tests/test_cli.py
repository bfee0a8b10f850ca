"""The prc-slam command line: classify outputs, demo, bench."""

from __future__ import annotations

import json

import laspy
import numpy as np
from typer.testing import CliRunner

from prc_slam.cli import app
from tests.test_readers import make_kitti

runner = CliRunner()


def test_classify_writes_labels_json_and_las(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=2)
    out = tmp_path / "out"
    res = runner.invoke(
        app,
        [
            "classify",
            str(root),
            "--preset",
            "multibeam",
            "--labels-out",
            str(out / "labels"),
            "--json",
            str(out / "m.json"),
            "--las",
            str(out / "c.las"),
        ],
    )
    assert res.exit_code == 0, res.output
    for i in range(2):
        n = (root / "velodyne" / f"{i:06d}.bin").stat().st_size // 16
        lab = np.fromfile(out / "labels" / f"{i:06d}.label", dtype=np.uint32)
        assert lab.size == n  # one entry per input point
        assert set(np.unique(lab & 0xFFFF)) <= {1, 2, 5, 6, 7}
    m = json.loads((out / "m.json").read_text())
    assert m["frames"] == 2 and m["points"] == 3200
    assert {"per_class", "confusion", "points_per_s", "seconds"} <= set(m)
    assert (out / "m.config.yaml").is_file()
    las = laspy.read(out / "c.las")
    assert len(las.points) == 3200 and las.header.version.minor == 4


def test_classify_reports_bad_input_cleanly(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=1)
    f = root / "velodyne" / "000000.bin"
    f.write_bytes(f.read_bytes()[:-3])
    res = runner.invoke(app, ["classify", str(root)])
    assert res.exit_code == 2
    assert "000000.bin: truncated" in res.output


def test_demo_runs(tmp_path):
    res = runner.invoke(app, ["demo", "--frames", "3", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "prc_metrics.json").read_text())
    assert m["frames"] == 3 and m["per_class"]["noise"]["recall"] > 0.8
    odo = json.loads((tmp_path / "metrics.json").read_text())
    assert set(odo["variants"]) == {"raw", "prc"} and (tmp_path / "report.md").is_file()
    again = runner.invoke(app, ["demo", "--frames", "3", "--out", str(tmp_path)])
    assert "(cached)" in again.output


def test_bench_json(tmp_path):
    res = runner.invoke(app, ["bench", "--kitti", str(tmp_path / "none"), "--json", str(tmp_path / "b.json")])
    assert res.exit_code == 0, res.output
    b = json.loads((tmp_path / "b.json").read_text())
    assert b["prc"]["points_per_s"] > 0 and b["prc"]["block_shape"] == [99, 2154]
    assert b["sim"]["rays_per_s"] > b["sim"]["frame_rays_per_s"] > 0


def test_simulate_then_classify(tmp_path):
    res = runner.invoke(
        app,
        [
            "simulate",
            "--out",
            str(tmp_path / "sim"),
            "--frames",
            "2",
            "--outlier-rate",
            "0.02",
            "--kitti",
            str(tmp_path / "kitti"),
        ],
    )
    assert res.exit_code == 0, res.output
    assert len(list((tmp_path / "sim" / "frames").glob("*.npz"))) == 2
    assert len(list((tmp_path / "kitti" / "velodyne").glob("*.bin"))) == 2
    assert (tmp_path / "kitti" / "sequences" / "00" / "velodyne").is_dir()
    res = runner.invoke(
        app, ["classify", str(tmp_path / "sim"), "--preset", "multibeam", "--json", str(tmp_path / "m.json")]
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["per_class"]["noise"]["recall"] > 0.8  # the 2 % outliers are found
    assert m["per_class"]["ground"]["recall"] > 0.8
    bad = runner.invoke(app, ["simulate", "--out", str(tmp_path / "x"), "--frames", "100000"])
    assert bad.exit_code == 2 and "needs" in bad.output


def test_ply_writer(tmp_path):
    from data_tools.writers import write_ply

    xyz = np.arange(12, dtype=np.float32).reshape(4, 3)
    write_ply(tmp_path / "c.ply", xyz, np.array([2, 5, 6, 7], np.uint8))
    raw = (tmp_path / "c.ply").read_bytes()
    header, body = raw.split(b"end_header\n")
    assert b"element vertex 4" in header and b"property uchar label" in header
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "u1")])
    np.testing.assert_array_equal(np.column_stack([rec["x"], rec["y"], rec["z"]]), xyz)
    assert rec["label"].tolist() == [2, 5, 6, 7]
