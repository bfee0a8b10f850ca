"""Map cloud coordinates: geographic degrees are refused, metric clouds at any offset are read,
an empty cloud is an error, a coarse LAS scale is warned once.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError


def write_las_cloud(path: Path, x: np.ndarray, y: np.ndarray, z: np.ndarray, scale: float) -> Path:
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale, scale, scale])
    header.offsets = np.array([x.min(), y.min(), z.min()])
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.write(path)
    return path


def block_scene(n: int = 2000, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground over 100 x 100 m with a 10 m high block."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 100, n), rng.uniform(0, 100, n)
    z = np.where((x > 30) & (x < 50) & (y > 30) & (y < 60), 10.0, 0.0) + rng.normal(0, 0.03, n)
    return x, y, z


def test_map_cloud_in_geographic_degrees_is_refused(tmp_path):
    """Longitude/latitude in degrees with heights in metres is refused: classified as is, most of it would come
    out as poles."""
    from data_tools.formats.clouds import cloud_chunks

    x, y, z = block_scene()
    path = write_las_cloud(tmp_path / "deg.las", 11.0 + x / 111_000, 48.0 + y / 111_000, z, 1e-7)
    with pytest.raises(DataError, match="geographic degrees"):
        list(cloud_chunks(path))
    np.save(tmp_path / "deg.npy", np.column_stack([11.0 + x / 111_000, 48.0 + y / 111_000, z]))
    with pytest.raises(DataError, match="geographic degrees"):
        list(cloud_chunks(tmp_path / "deg.npy"))


@pytest.mark.parametrize("offset", [(0.0, 0.0), (500_000.0, 5_400_000.0), (-170.0, 80.0)])
def test_metric_map_clouds_are_read(tmp_path, offset):
    """Metric clouds near the origin, in UTM, or near (-170, 80) m are read unchanged."""
    from data_tools.formats.clouds import cloud_chunks

    x, y, z = block_scene()
    path = write_las_cloud(tmp_path / "m.las", x + offset[0], y + offset[1], z, 0.001)
    xyz = np.concatenate(list(cloud_chunks(path)))
    np.testing.assert_allclose(xyz, np.column_stack([x + offset[0], y + offset[1], z]), atol=1e-3)


def test_an_empty_map_cloud_is_an_error(tmp_path):
    """An empty map cloud is an error, not a run that exits 0 with empty outputs."""
    import laspy
    from typer.testing import CliRunner

    from prc_slam.cli import app

    path = tmp_path / "empty.las"
    laspy.LasData(laspy.LasHeader(point_format=6, version="1.4")).write(path)
    res = CliRunner().invoke(app, ["mapclass", str(path), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "empty.las: the cloud holds no points" in res.output


def test_coarse_las_scale_is_warned_once(tmp_path, caplog):
    from data_tools.formats.clouds import cloud_chunks

    x, y, z = block_scene()
    path = write_las_cloud(tmp_path / "coarse.las", x, y, z, 1.0)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        list(cloud_chunks(path))
        list(cloud_chunks(path))
    assert sum("quantised to 1" in r.getMessage() for r in caplog.records) == 1
