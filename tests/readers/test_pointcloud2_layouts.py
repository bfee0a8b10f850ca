"""PointCloud2 point layouts as real drivers publish them (field order, padding, datatypes, byte order)
give the same labels.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.inputs.pointcloud2 import EPOCH_NS, VELODYNE_LAYOUT, vlp16_records

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
