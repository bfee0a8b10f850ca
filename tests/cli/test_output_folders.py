"""A second run into the same folder leaves no class files of the first."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.inputs.las import ground_and_wall, write_las

laspy = pytest.importorskip("laspy")


def test_a_second_run_into_the_same_folder_leaves_no_class_files_of_the_first(tmp_path):
    """Classifying a building tile and then a bare field into the same ``--out`` leaves no ``building.las`` of
    the first run (nor its ``.las`` files beside a later ``--laz`` run's); files the command did not write stay."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = ground_and_wall(3000)
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
