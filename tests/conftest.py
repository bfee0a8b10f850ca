"""Shared fixtures: the real data in ../shared/data (tests skip with a clear message when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
KITTI00 = SHARED_DATA / "kitti00"
OUSTER_DECODED = SHARED_DATA / "ouster" / "decoded"


@pytest.fixture(scope="package")
def kitti_dir() -> Path:
    if not (KITTI00 / "velodyne").is_dir():
        pytest.skip(f"real KITTI data not found at {KITTI00} (expected ../shared/data beside the repo)")
    return KITTI00


@pytest.fixture(scope="package")
def ouster_files() -> list[Path]:
    files = sorted(OUSTER_DECODED.glob("*.npz"))
    if not files:
        pytest.skip(f"decoded Ouster sweeps not found in {OUSTER_DECODED}")
    return files
