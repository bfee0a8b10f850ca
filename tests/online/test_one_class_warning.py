"""``detect`` warns when one class takes every return, and not on real sweeps."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import SHARED_DATA


def test_detect_warns_when_one_class_takes_every_return(caplog):
    """``detect`` on a flat 80 m x 80 m aerial-like tile (every return 'vertical') warns that one class took
    every return (PRC's one-class check does not see the detectors' labels). Hand case on the sink: 1,200
    returns of one class are warned once and counted; a frame of two classes is not."""
    import logging
    from types import SimpleNamespace

    from prc_slam import labels as L
    from prc_slam.jobs.classify import OneClassWatch

    ranges = np.ones(1500)
    ranges[:300] = 0  # slots without a return do not count
    one = np.full(1500, L.VERTICAL, np.uint8)
    two = one.copy()
    two[300:800] = L.GROUND

    def step(labels):
        return SimpleNamespace(online=SimpleNamespace(labels=labels), scan=SimpleNamespace(ranges=ranges, source="t"))

    watch = OneClassWatch()
    with caplog.at_level(logging.WARNING, logger="prc_slam.jobs"):
        watch.frame(step(two))
        assert watch.frames == 0 and not caplog.records
        watch.frame(step(one))
        watch.frame(step(one))
    assert watch.frames == 2
    assert [r.getMessage() for r in caplog.records] == [
        "t: the online detectors put 100.0% of the returns in one class (vertical): is this a sweep of a spinning "
        "sensor (not a map or an aerial tile: use mapclass), in metres?"
    ]


def test_detect_on_real_sweeps_is_not_warned_of_one_class(caplog):
    import logging

    from data_tools.datasets import open_dataset
    from prc_slam.jobs.classify import detect_job

    path = SHARED_DATA / "multisensor" / "velodyne_vlp16.pcd"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    with caplog.at_level(logging.WARNING, logger="prc_slam.jobs"):
        metrics, _ = detect_job(path)
    assert metrics["frames_one_class"] == 0 and "one class" not in caplog.text
    assert metrics["points"] == open_dataset(path)[0].n_points
