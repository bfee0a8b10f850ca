"""PointCloud2 point layouts as real drivers publish them (field order, padding, datatypes, byte order)
give the same labels.
"""

from __future__ import annotations

import numpy as np
import pytest

EPOCH_NS = 1_700_000_000 * 10**9


def vlp16_records(layout: list[tuple[str, str, int]], itemsize: int, *, big: bool = False) -> np.ndarray:
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


VELODYNE_LAYOUT = [("x", "f4", 0), ("y", "f4", 4), ("z", "f4", 8), ("intensity", "f4", 12), ("ring", "u2", 16)]


VELODYNE_LAYOUT += [("time", "f4", 18)]


XYZ = VELODYNE_LAYOUT[:3]


DRIVER_LAYOUTS = {  # as real drivers publish them: field order, padding, datatypes, byte order
    "reordered_padded": ([(n, t, 40 - 4 * (k + 1)) for k, (n, t, _) in enumerate(VELODYNE_LAYOUT)], 40, False),
    "intensity_ring_uint8": ([*XYZ, ("intensity", "u1", 12), ("ring", "u1", 13), ("time", "f4", 14)], 18, False),
    "intensity_ring_uint16": ([*XYZ, ("intensity", "u2", 12), ("ring", "u2", 14), ("time", "f4", 16)], 20, False),
    "time_float64": ([*VELODYNE_LAYOUT[:5], ("time", "f8", 18)], 26, False),
    "bigendian": (VELODYNE_LAYOUT, 22, True),
}


def prc_labels_of(rec: np.ndarray, **cloud_kw) -> np.ndarray:
    from data_tools.formats.rosbag import cloud_from_records, cloud_to_scan, detect_time_field
    from data_tools.organize import Organizer
    from prc_slam.prc import classify_scan
    from prc_slam.prc.config import PRCConfig

    cloud = cloud_from_records(rec, stamp_ns=EPOCH_NS, **cloud_kw)
    scan = cloud_to_scan(
        cloud, Organizer(sweep_period=0.1), name="000000", source="test", time_field=detect_time_field(cloud, 0.1)
    )
    labels = scan.per_point(classify_scan(scan, PRCConfig.preset("multibeam")))
    assert labels.shape == (len(rec),)
    return labels


@pytest.mark.parametrize("layout", sorted(DRIVER_LAYOUTS))
def test_driver_point_layouts_of_a_real_sweep_give_the_same_labels(layout):
    """The real VLP-16 sweep in every driver's point layout (ROS 1 / ROS 2 / MCAP through ``classify``) gives
    the labels of the reference layout (velodyne_pointcloud's)."""
    fields, itemsize, big = DRIVER_LAYOUTS[layout]
    ref = prc_labels_of(vlp16_records(VELODYNE_LAYOUT, 22))
    np.testing.assert_array_equal(prc_labels_of(vlp16_records(fields, itemsize, big=big)), ref)
