"""Label files beside the sweeps: a file that does not fit its sweep leaves the frame classified, files
that are not SemanticKITTI labels are warned.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from tests.inputs.kitti import kitti_folder


def _with_labels(root: Path, bad: np.ndarray | None) -> None:
    """SemanticKITTI labels (road, 40) for every sweep of ``root``; sweep 1's file holds ``bad``
    (given the right count) instead."""
    (root / "labels").mkdir()
    for i, f in enumerate(sorted((root / "velodyne").glob("*.bin"))):
        n = f.stat().st_size // 16
        lab = np.full(n, 40, np.uint32) if i != 1 or bad is None else bad(n)
        lab.tofile(root / "labels" / (f.stem + ".label"))


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (lambda n: np.full(n - 3, 40, np.uint32), "labels for"),
        (lambda n: np.full(n, 40, np.uint16), "one uint16 per point? SemanticKITTI labels are uint32"),
        (lambda n: np.full(n, 40, np.uint64), "one uint64 per point? SemanticKITTI labels are uint32"),
    ],
    ids=["count", "uint16", "uint64"],
)
def test_a_label_file_that_does_not_fit_leaves_its_frame_classified(tmp_path, bad, message):
    """A label file that does not fit its sweep (point count, integer width) leaves the frame classified,
    written and registered by odometry; only its scores are left out, with a warning."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    root = kitti_folder(tmp_path / "seq", [0, 1, 2], 3)
    _with_labels(root, bad)
    res = CliRunner().invoke(app, ["classify", str(root), "--labels-out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "000001.label" in text and message in text and "this frame is not scored" in text
    assert "skipped" not in text
    for f in sorted((root / "velodyne").glob("*.bin")):
        written = np.fromfile(tmp_path / "out" / (f.stem + ".label"), np.uint32)
        assert len(written) == f.stat().st_size // 16


def test_label_files_that_are_not_semantic_kitti_are_warned(tmp_path, caplog):
    from data_tools.formats.kitti import KittiSequence

    root = kitti_folder(tmp_path / "seq", [0, 1, 2], 3)
    _with_labels(root, lambda n: np.random.default_rng(0).integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32))
    seq = KittiSequence(root)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        seq[0]
        assert not caplog.records  # road everywhere: SemanticKITTI's
        seq[1]
    assert "000001.label" in caplog.text and "not SemanticKITTI labels?" in caplog.text
