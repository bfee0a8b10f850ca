"""A truncated LAZ map is a one-line error."""

from __future__ import annotations

import numpy as np


def block_scene(n: int = 30_000, seed: int = 0) -> np.ndarray:
    """A 60 m x 60 m ground with a 20 m x 15 m x 8 m block building (roof and four walls)."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(0, 60, n), rng.uniform(0, 60, n), rng.normal(0, 0.02, n)])
    ground = ground[~((ground[:, 0] > 20) & (ground[:, 0] < 40) & (ground[:, 1] > 20) & (ground[:, 1] < 35))]
    m = n // 4
    roof = np.column_stack([rng.uniform(20, 40, m), rng.uniform(20, 35, m), 8 + rng.normal(0, 0.02, m)])
    walls = []
    for x0, x1, y0, y1 in ((20, 40, 20, 20), (20, 40, 35, 35), (20, 20, 20, 35), (40, 40, 20, 35)):
        t, h = rng.uniform(0, 1, m // 2), rng.uniform(0, 8, m // 2)
        walls.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), h]))
    return np.concatenate([ground, roof, *walls])


def test_a_truncated_laz_map_is_a_one_line_error(tmp_path):
    """A truncated LAZ map given to ``mapclass`` is a one-line error naming the file (no ``lazrs`` traceback)."""
    import laspy
    from typer.testing import CliRunner

    from prc_slam.cli import app

    xyz = block_scene(3000)
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
