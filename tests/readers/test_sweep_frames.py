"""Sweeps that are not in the sensor's frame: a folder of sweeps in a world frame is told apart from
one in millimetres, and a recording of registered clouds is warned.
"""

from __future__ import annotations

import logging

import numpy as np

from data_tools.formats.pcd import write_pcd
from tests.inputs.clouds import UTM


def test_sweeps_in_a_world_frame_are_told_apart_from_millimetres(tmp_path, caplog):
    """A sweep written in UTM coordinates is warned as being in a world frame, not as 'not in metres
    (millimetres? centimetres?)', which would send the user to convert units that are right."""
    import contextlib

    from data_tools import DataError
    from data_tools.formats.pcd import SweepFolder
    from prc_slam.scan import ScanError
    from tests.inputs.grids import spinning_grid

    g = spinning_grid().reshape(-1, 3).astype(np.float64)
    g = g[np.isfinite(g).all(axis=1)]
    for name, xyz in (("utm", g + UTM), ("local", g + np.array([400.0, -150.0, 2.0])), ("mm", g * 1000.0), ("m", g)):
        folder = tmp_path / name
        folder.mkdir()
        write_pcd(folder / "000000.pcd", {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
            with contextlib.suppress(DataError, ScanError):  # the organiser may refuse it: the warning is tested
                SweepFolder(folder)[0]
        text = caplog.text
        if name in ("utm", "local"):
            assert "in a world or map frame, not their sensor's" in text and "millimetres" not in text
        else:
            assert ("not in metres (millimetres?" in text) == (name == "mm") and "world or map frame" not in text


def test_a_recording_of_registered_clouds_is_warned(tmp_path, caplog):
    """A bag topic of clouds already in the map frame (FAST-LIO's ``/cloud_registered``, 300 m from the origin)
    is warned as registered clouds."""
    import contextlib

    from data_tools import DataError
    from data_tools.formats.rosbag import RosbagSequence, cloud_from_records
    from data_tools.formats.stream_out import RosCloudWriter
    from tests.inputs.grids import spinning_grid

    g = spinning_grid().reshape(-1, 3)
    g = g[np.isfinite(g).all(axis=1)]
    for name, offset, frame in (("map", (300.0, -120.0, 5.0), "camera_init"), ("sensor", (0.0, 0.0, 0.0), "lidar")):
        rec = np.zeros(len(g), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
        for k, c in enumerate("xyz"):
            rec[c] = g[:, k] + offset[k]
        with RosCloudWriter(tmp_path / f"{name}.mcap", "mcap", "/cloud") as w:
            for i in range(2):
                w.write_cloud(cloud_from_records(rec, frame_id=frame, stamp_ns=(i + 1) * 100_000_000, seq=i))
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
            with RosbagSequence(tmp_path / f"{name}.mcap") as seq:
                for i in range(2):
                    with contextlib.suppress(DataError):  # the organiser may refuse it: the warning is tested
                        seq[i]
        warned = [r.getMessage() for r in caplog.records if "world or map frame" in r.getMessage()]
        assert len(warned) == (name == "map")
        if warned:
            assert "frame 'camera_init'" in warned[0] and "/cloud" in warned[0]
