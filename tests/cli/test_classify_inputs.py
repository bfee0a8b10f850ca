"""``classify`` on inputs of every kind runs or says why; its summary counts points at the origin as
points without a return.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from data_tools.formats.rosbag import cloud_from_records
from tests.inputs.pointcloud2 import EPOCH_NS
from tests.inputs.rosbags import ros2_sweeps, write_ros2
from tests.inputs.velodyne import velodyne32_stream, write_pcap


def test_the_summary_counts_points_at_the_origin_as_points_without_a_return(tmp_path):
    """An organised cloud whose no-returns are zeros (Ouster driver): the summary called them
    'non-finite points'."""
    from typer.testing import CliRunner

    from data_tools.formats.stream_out import RosCloudWriter
    from prc_slam.cli import app
    from tests.inputs.grids import spinning_grid

    grid = np.nan_to_num(spinning_grid(beams=16, cols=512), nan=0.0)
    rec = np.zeros(grid.shape[:2], [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", "<u2")])
    rec["x"], rec["y"], rec["z"] = grid[..., 0], grid[..., 1], grid[..., 2]
    rec["ring"] = np.arange(16)[:, None]
    path = tmp_path / "zeros.bag"
    with RosCloudWriter(path, "ros1", "/points") as w:
        w.write_cloud(cloud_from_records(rec.ravel(), height=16, stamp_ns=EPOCH_NS))
    res = CliRunner().invoke(app, ["classify", str(path)])
    assert res.exit_code == 0, res.output
    zeros = int((grid == 0).all(axis=-1).sum())
    assert f"{zeros} points without a return" in res.output and "non-finite" not in res.output


def test_classify_on_new_inputs_runs_or_says_why(tmp_path):
    """``prc-slam classify`` on a file-compressed MCAP bag and a VLP-32C capture counts every
    point; on an Ouster capture with another mode's json and on a Hesai capture it is one
    ``error:`` line (exit 2)."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    from typer.testing import CliRunner

    from prc_slam.cli import app

    msgs, recs = ros2_sweeps()
    bag = write_ros2(tmp_path / "bag", msgs, storage="mcap", compression="FILE")
    vlp32 = write_pcap(tmp_path / "vlp32c.pcap", *velodyne32_stream(0x28, n_sweeps=2.2))
    runner = CliRunner()
    for given, points in ((bag, sum(len(r) for r in recs)), (vlp32, None)):
        out = tmp_path / f"{given.stem}.json"
        res = runner.invoke(app, ["classify", str(given), "--json", str(out)])
        assert res.exit_code == 0, res.output
        metrics = json.loads(out.read_text())
        assert metrics["frames"] == (2 if points else 3)
        if points:
            assert metrics["points"] == points
    hesai = write_pcap(tmp_path / "hesai.pcap", [b"\xee\xff" + bytes(1078)] * 20, [1e9 + k * 1e-4 for k in range(20)])
    res = runner.invoke(app, ["classify", str(hesai)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Hesai" in errors[0], res.output
