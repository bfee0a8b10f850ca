"""The prc-slam command line: classify outputs, demo, bench."""

from __future__ import annotations

import json

import laspy
import numpy as np
from typer.testing import CliRunner

from prc_slam.cli import app
from tests.inputs.kitti import make_kitti

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
    n_points = sum((root / "velodyne" / f"{i:06d}.bin").stat().st_size // 16 for i in range(2))
    assert m["frames"] == 2 and m["points"] == n_points
    assert {"per_class", "confusion", "points_per_s", "seconds"} <= set(m)
    assert (out / "m.config.yaml").is_file()
    las = laspy.read(out / "c.las")
    assert len(las.points) == n_points and las.header.version.minor == 4


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
    assert b["sim"]["rays_per_s"] > 0 and b["sim"]["frame_rays_per_s"] > 0  # (no ratio of timings: a loaded machine)


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
    from data_tools.formats.writers import write_ply

    xyz = np.arange(12, dtype=np.float32).reshape(4, 3)
    write_ply(tmp_path / "c.ply", xyz, np.array([2, 5, 6, 7], np.uint8))
    raw = (tmp_path / "c.ply").read_bytes()
    header, body = raw.split(b"end_header\n")
    assert b"element vertex 4" in header and b"property uchar label" in header
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "u1")])
    np.testing.assert_array_equal(np.column_stack([rec["x"], rec["y"], rec["z"]]), xyz)
    assert rec["label"].tolist() == [2, 5, 6, 7]


STREET_GROUND_POINTS = 200 * 200


def _street_cloud(n_side: int = 200) -> np.ndarray:
    """A small map: a 12 m ground plane and a 5 m wall along one side (6 cm spacing)."""
    g = np.linspace(0, 12, n_side)
    x, y = np.meshgrid(g, g, indexing="ij")
    ground = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    z = np.linspace(0, 5, 80)
    xw, zw = np.meshgrid(g, z, indexing="ij")
    wall = np.column_stack([xw.ravel(), np.full(xw.size, 12.0), zw.ravel()])
    return np.concatenate([ground, wall])


def test_mapclass_on_cloud_files_segregates_every_point(tmp_path):
    from data_tools.formats.writers import write_ply

    pts = _street_cloud()
    write_ply(tmp_path / "map.ply", pts)
    out = tmp_path / "out"
    rrd = tmp_path / "map.rrd"
    res = runner.invoke(
        app,
        [
            "mapclass",
            str(tmp_path / "map.ply"),
            "--out",
            str(out),
            "--json",
            str(tmp_path / "m.json"),
            "--rrd",
            str(rrd),
        ],
    )
    assert res.exit_code == 0, res.output
    import rerun.chunk as rc

    assert "/world/map_classified/part_0" in {c.entity_path for c in rc.RrdReader(str(rrd)).store().stream()}
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["points"] == len(pts) == sum(m["counts"].values())
    combined = laspy.read(out / "map_classified.las")
    assert combined.header.version.minor == 4 and len(combined.points) == len(pts)
    per_class = {p.stem: laspy.read(p) for p in out.glob("*.las") if p.stem != "map_classified"}
    assert sum(len(c.points) for c in per_class.values()) == len(pts)
    for name, las in per_class.items():
        assert set(np.unique(las.classification)) == {m_code(name)}
    assert m["counts"]["ground"] > 0.9 * STREET_GROUND_POINTS and m["counts"]["building"] > 0.8 * (
        len(pts) - STREET_GROUND_POINTS
    )
    # the combined LAS as input, tiled: same number of points, border effects small
    res = runner.invoke(
        app,
        [
            "mapclass",
            str(out / "map_classified.las"),
            "--tile",
            "5",
            "--out",
            str(tmp_path / "o2"),
            "--json",
            str(tmp_path / "t.json"),
        ],
    )
    assert res.exit_code == 0, res.output
    t = json.loads((tmp_path / "t.json").read_text())
    assert t["points"] == len(pts) and t["tile"] == 5.0
    again = laspy.read(tmp_path / "o2" / "map_classified.las")
    assert np.mean(np.asarray(again.classification) != np.asarray(combined.classification)) < 0.1


def m_code(name: str) -> int:
    from prc_slam import labels as L

    return L.NAME_TO_CODE[name]


def test_mapclass_reports_bad_files_cleanly(tmp_path):
    from data_tools.formats.writers import write_las

    write_las(tmp_path / "a.las", _street_cloud(20), np.zeros(20 * 20 + 20 * 80, np.uint8))
    data = (tmp_path / "a.las").read_bytes()
    (tmp_path / "cut.las").write_bytes(data[: len(data) // 2])
    res = runner.invoke(app, ["mapclass", str(tmp_path / "cut.las"), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "cut.las" in res.output
    np.save(tmp_path / "bad.npy", np.zeros((10, 2)))
    res = runner.invoke(app, ["mapclass", str(tmp_path / "bad.npy"), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "bad.npy" in res.output and "(N, 3)" in res.output
    res = runner.invoke(app, ["mapclass", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2


def test_mapclass_on_a_sequence_and_compare_mapclass(tmp_path):
    res = runner.invoke(app, ["simulate", "--out", str(tmp_path / "sim"), "--frames", "4"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(
        app, ["mapclass", str(tmp_path / "sim"), "--out", str(tmp_path / "mc"), "--json", str(tmp_path / "m.json")]
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["per_class"]["ground"]["recall"] > 0.9 and set(m["objects"]) == {"vehicle", "pole"}
    res = runner.invoke(
        app, ["compare", str(tmp_path / "sim"), "--out", str(tmp_path / "cmp"), "--mapclass", "--mapclass-every", "2"]
    )
    assert res.exit_code == 0, res.output
    mc = json.loads((tmp_path / "cmp" / "mapclass.json").read_text())
    assert mc["poses"] == "prc" and mc["prc_vs_map"]["per_class"]["ground"]["support"] > 0
    assert "Map classification after registration" in (tmp_path / "cmp" / "report.md").read_text()
