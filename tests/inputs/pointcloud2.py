"""The real VLP-16 sweep as PointCloud2 point records in the layouts drivers publish."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

#: velodyne_pointcloud's PointXYZIRT as ``(name, numpy type, offset)``, 22 bytes a point
VELODYNE_LAYOUT = (
    ("x", "f4", 0),
    ("y", "f4", 4),
    ("z", "f4", 8),
    ("intensity", "f4", 12),
    ("ring", "u2", 16),
    ("time", "f4", 18),
)


EPOCH_NS = 1_700_000_000 * 10**9


def vlp16_records(layout: Sequence[tuple[str, str, int]], itemsize: int, *, big: bool = False) -> np.ndarray:
    """The real VLP-16 sweep (``multisensor/velodyne_vlp16.pcd``) in a PointCloud2 point layout
    ``(name, numpy type, offset)``: ring from its ``channel``, time (s) from the azimuth."""
    from data_tools.formats.pcd import read_pcd
    from tests.conftest import SHARED_DATA

    path = SHARED_DATA / "multisensor" / "velodyne_vlp16.pcd"
    if not path.is_file():
        pytest.skip(f"real VLP-16 sweep not found: {path}")
    f, _ = read_pcd(path)
    f = {**f, "ring": f["channel"], "time": (np.arctan2(f["y"], f["x"]) % (2 * np.pi)) / (2 * np.pi) * 0.1 - 0.1}
    o = ">" if big else "<"
    dt = np.dtype(
        {
            "names": [n for n, _, _ in layout],
            "formats": [o + t for _, t, _ in layout],
            "offsets": [k for _, _, k in layout],
            "itemsize": itemsize,
        }
    )
    rec = np.zeros(len(f["x"]), dt)
    for name, _, _ in layout:
        rec[name] = f[name]
    return rec
