"""A truncated LAZ map is a one-line error."""

from __future__ import annotations

import numpy as np

from tests.inputs.clouds import block_building


def test_a_truncated_laz_map_is_a_one_line_error(tmp_path):
    """A truncated LAZ map given to ``mapclass`` is a one-line error naming the file (no ``lazrs`` traceback)."""
    import laspy
    from typer.testing import CliRunner

    from prc_slam.cli import app

    xyz = block_building(3000)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.classification = np.full(len(xyz), 2, np.uint8)
    las.write(tmp_path / "whole.laz")
    cut = tmp_path / "cut.laz"
    cut.write_bytes((tmp_path / "whole.laz").read_bytes()[:3000])
    res = CliRunner().invoke(app, ["mapclass", str(cut), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and (res.exception is None or isinstance(res.exception, SystemExit)), res.output
    assert "cut.laz: not a readable LAS file" in " ".join(res.output.split())
