"""A second run into the same folder leaves no class files of the first."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")


def block_scene(n: int = 6000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 40 m x 40 m ground (ASPRS 2) with a 20 m wall 8 m high (ASPRS 6): points, classes."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(0, 40, n), rng.uniform(0, 40, n), rng.normal(0, 0.02, n)])
    m = n // 3
    wall = np.column_stack([rng.uniform(10, 30, m), np.full(m, 30.0) + rng.normal(0, 0.02, m), rng.uniform(0, 8, m)])
    return np.concatenate([ground, wall]), np.concatenate([np.full(n, 2), np.full(m, 6)]).astype(np.uint8)


def write_las(
    path: Path,
    xyz: np.ndarray,
    classes: np.ndarray | None = None,
    *,
    scale: float = 0.001,
    offset: np.ndarray | None = None,
    point_format: int = 6,
    withheld: np.ndarray | None = None,
) -> Path:
    version = "1.4" if point_format >= 6 else "1.2"
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(xyz.min(axis=0)) if offset is None else offset
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    if classes is not None:
        las.classification = classes
    if withheld is not None:
        las.withheld = withheld
    las.write(path)
    return path


def test_a_second_run_into_the_same_folder_leaves_no_class_files_of_the_first(tmp_path):
    """Classifying a building tile and then a bare field into the same ``--out`` leaves no ``building.las`` of
    the first run (nor its ``.las`` files beside a later ``--laz`` run's); files the command did not write stay."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = block_scene(3000)
    write_las(tmp_path / "tile.las", xyz, classes)
    rng = np.random.default_rng(5)
    field = np.column_stack([rng.uniform(0, 40, 4000), rng.uniform(0, 40, 4000), rng.normal(0, 0.02, 4000)])
    np.save(tmp_path / "field.npy", field)
    out = tmp_path / "out"
    first = mapclass_job(tmp_path / "tile.las", Config(), out)
    assert "building" in first["files"]
    (out / "notes.las").write_bytes(b"mine")
    second = mapclass_job(tmp_path / "field.npy", Config(), out, laz=True)
    assert "building" not in second["files"]
    assert sorted(f.name for f in out.iterdir() if f.is_file()) == sorted(
        [Path(p).name for p in second["files"].values()] + ["notes.las"]
    )
