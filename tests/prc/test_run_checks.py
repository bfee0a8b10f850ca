"""What every ``classify`` run says of its labels, with ground truth or without: the share of
each class (``classes``), and a warning when PRC calls a quarter of a frame's returns noise.

A run on unlabelled sweeps reports its class shares, and the shared Hesai AT128 sweep (a
mirror-scanning sensor organised as a 68-beam spinning one), 45 % noise, is said.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from prc_slam import labels as L
from prc_slam.cli import app
from prc_slam.evaluation.scoring import class_shares
from prc_slam.pipeline import NOISE_WARN_SHARE, noise_share
from tests.conftest import SHARED_DATA

runner = CliRunner()
MULTISENSOR = SHARED_DATA / "multisensor"


def test_class_shares_hand_case():
    counts = np.zeros(256, np.int64)
    counts[[L.NO_RETURN, L.GROUND, L.NOISE, L.BUILDING]] = [50, 30, 10, 60]
    out = class_shares(counts)
    assert list(out) == ["building", "ground", "noise"]  # largest first, no-return left out
    assert out["ground"] == {"points": 30, "share": 0.3}
    assert sum(c["share"] for c in out.values()) == pytest.approx(1.0)
    assert class_shares(np.zeros(256, np.int64)) == {}


def test_noise_share_counts_returns_only():
    ranges = np.ones((4, 500))
    ranges[0] = 0.0  # 1500 returns
    labels = np.full(ranges.shape, L.GROUND, np.uint8)
    labels[0] = L.NOISE  # slots without a return do not count
    labels[1, :375] = L.NOISE
    assert noise_share(labels, ranges) == pytest.approx(375 / 1500) == NOISE_WARN_SHARE
    assert noise_share(labels[:, :100], ranges[:, :100]) is None  # under 1000 returns: not judged


def _classify(path, tmp_path):
    out = tmp_path / f"{path.stem}.json"
    res = runner.invoke(app, ["classify", str(path), "--max-frames", "3", "--json", str(out)])
    assert res.exit_code == 0, res.output
    return res.output, json.loads(out.read_text())


def test_unlabelled_real_sweeps_report_their_classes_and_are_not_warned_of_noise(tmp_path):
    files = sorted(MULTISENSOR.glob("*.pcd"))
    files = [f for f in files if "at128" not in f.name]
    if not files:
        pytest.skip(f"real sweeps not found in {MULTISENSOR}")
    for f in files:
        output, m = _classify(f, tmp_path)
        assert "per_class" not in m and "frames_mostly_noise" not in m, f.name
        shares = m["classes"]
        assert {"ground", "building"} <= set(shares) and sum(c["points"] for c in shares.values()) == m["points"]
        assert shares["noise"]["share"] < 0.05 if "noise" in shares else True
        assert "classes (share of the returns): " in output and "noise (isolated)" not in output, output


def test_a_sensor_organised_wrongly_is_warned_of_its_noise(tmp_path):
    f = MULTISENSOR / "hesai_at128.pcd"
    if not f.is_file():
        pytest.skip(f"real sweep not found: {f}")
    output, m = _classify(f, tmp_path)
    assert m["frames_mostly_noise"] == 1 and m["classes"]["noise"]["share"] > NOISE_WARN_SHARE
    warned = [line for line in output.splitlines() if "noise (isolated)" in line]
    assert len(warned) == 1 and "hesai_at128.pcd" in warned[0] and re.search(r"\d+ x \d+ slots", warned[0]), output
