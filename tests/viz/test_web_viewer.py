"""The Rerun web viewer served by ``--serve-web``, seen rendering in a real Chromium.

Runs ``scripts/check_web_viewer.py``: a short simulated comparison served with ``--serve-web``,
opened in Debian's Chromium on a virtual screen (Xvfb, software rasteriser), screenshot through the
DevTools protocol until the 3-D view shows the point cloud. The screenshot stays in
``out/web_viewer.png`` (the CI artefact)."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("check_web_viewer", ROOT / "scripts" / "check_web_viewer.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_cloud_pixels_tells_a_blank_view_from_a_cloud(tmp_path):
    import numpy as np
    from PIL import Image

    check = _script()
    blank = np.full((800, 1280, 3), 245, np.uint8)
    Image.fromarray(blank).save(tmp_path / "blank.png")
    assert check.cloud_pixels(tmp_path / "blank.png") == 0.0
    cloud = blank.copy()
    cloud[300:500, 300:600] = (200, 40, 40)  # a red building in the 3-D view
    Image.fromarray(cloud).save(tmp_path / "cloud.png")
    assert check.cloud_pixels(tmp_path / "cloud.png") > 0.1


def test_web_viewer_renders_the_cloud_in_chromium(tmp_path):
    if shutil.which("Xvfb") is None or shutil.which("chromium") is None:
        pytest.skip("needs Debian's chromium and xvfb (scripts/ensure_system_deps.sh installs them)")
    pytest.importorskip("playwright.sync_api", reason="needs playwright (the dev extra)")
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    check = _script()
    sequence = write_sequence(Simulator(SimConfig(frames=3, seed=4)), tmp_path / "sim")
    shot = ROOT / "out" / "web_viewer.png"
    ok, share = check.check(sequence, shot, timeout=150.0)
    assert shot.is_file()
    assert ok, f"the 3-D view stayed blank ({share:.3%} cloud pixels); see {shot}"
