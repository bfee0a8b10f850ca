"""Ouster lidar modes and profiles read every pixel; metadata of another lidar mode than the capture's is
a one-line error; a Hesai capture says what it is.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from tests.conftest import SHARED_DATA
from tests.inputs.velodyne import write_pcap
from tests.messages import one_line

OUSTER_JSON = SHARED_DATA / "ouster" / "pcaps" / "OS-1-128_v2.3.0_1024x10.json"


def ouster_capture(root: Path, name: str, mode: str, profile: str, frames: int = 2) -> tuple[Path, list]:
    """A capture of ``frames`` sweeps (ranges in mm, measurement order) in ``mode`` / ``profile``
    from the OS-1-128's metadata, written with ouster-sdk; its json beside it."""
    core = pytest.importorskip("ouster.sdk.core")
    from ouster.sdk import pcap

    if not OUSTER_JSON.is_file():
        pytest.skip(f"Ouster metadata not found: {OUSTER_JSON}")
    meta = json.loads(OUSTER_JSON.read_text())
    cols, hz = (int(v) for v in mode.split("x"))
    fmt = meta["data_format"]
    meta["lidar_mode"] = mode
    fmt.update(columns_per_frame=cols, column_window=[0, cols - 1], udp_profile_lidar=profile)
    fmt["pixel_shift_by_row"] = [s * cols // 1024 for s in fmt["pixel_shift_by_row"]]
    (root / f"{name}.json").write_text(json.dumps(meta))
    info = core.SensorInfo(json.dumps(meta))
    packet_format = core.PacketFormat(info)
    rng = np.random.default_rng(0)
    packets, truth = [], []
    for f in range(frames):
        frame = core.LidarFrame(info)
        r = 5000 + 1000 * np.sin(np.linspace(0, 6 * np.pi, cols))[None, :] + 10 * np.arange(128)[:, None]
        r = r.astype(np.uint32)
        r[rng.random(r.shape) < 0.05] = 0
        frame.field("RANGE")[:] = r
        if frame.has_field("RANGE2"):
            frame.field("RANGE2")[:] = np.where(r > 0, r + 2000, 0)
        frame.frame_id = 100 + f
        frame.timestamp[:] = 10**18 + f * 10**9 // hz + np.arange(cols, dtype=np.uint64) * (10**9 // hz // cols)
        frame.status[:] = 1
        frame.measurement_id[:] = np.arange(cols)
        packets += list(core.frame_to_packets(frame, packet_format, info.init_id, int(info.sn)))
        truth.append(r)
    path = root / f"{name}.pcap"
    pcap.record(packets, str(path), lidar_port=7502)
    return path, truth


@pytest.mark.parametrize(
    "mode, profile, resolution_mm",
    [
        ("512x10", "RNG19_RFL8_SIG16_NIR16", 0),
        ("2048x10", "RNG19_RFL8_SIG16_NIR16", 0),
        ("1024x20", "LEGACY", 0),
        ("1024x10", "RNG15_RFL8_NIR8", 8),
        ("1024x10", "RNG19_RFL8_SIG16_NIR16_DUAL", 0),
    ],
)
def test_ouster_lidar_modes_and_profiles_read_every_pixel(tmp_path, caplog, mode, profile, resolution_mm):
    """Every lidar mode (512x10, 1024x20, 2048x10) and profile reads every pixel at the profile's range
    resolution; a dual-return profile reads its first return and warns that the second is dropped."""
    path, truth = ouster_capture(tmp_path, "cap", mode, profile)
    cols, hz = (int(v) for v in mode.split("x"))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        ds = open_dataset(path, destaggered=False)  # measurement order, as the packets were written
        scans = list(ds)
    assert len(scans) == 2
    np.testing.assert_allclose(np.diff(ds.times), 1.0 / hz, rtol=1e-3)
    for scan, r in zip(scans, truth, strict=True):
        assert scan.shape == (128, cols)
        got = np.round(scan.ranges * 1000).astype(np.int64)
        assert ((got > 0) == (r > 0)).all()
        assert np.abs(got - r).max() <= resolution_mm
    dual = [rec.message for rec in caplog.records if "second returns (RANGE2) are not read" in rec.message]
    assert len(dual) == (1 if profile.endswith("DUAL") else 0)
    assert not [rec for rec in caplog.records if "columns missing" in rec.message]


@pytest.mark.parametrize("capture_mode, json_mode", [("2048x10", "1024x10"), ("512x10", "1024x10")])
def test_ouster_metadata_of_another_lidar_mode_is_a_one_line_error(tmp_path, capture_mode, json_mode):
    """Metadata of another lidar mode than the capture's (a 2048- or 512-column capture with a 1024x10 json) is
    a one-line error naming the measurement ids and the mode, not sweeps with half the points lost or every
    point at twice its azimuth."""
    path, _ = ouster_capture(tmp_path, "cap", capture_mode, "RNG19_RFL8_SIG16_NIR16")
    ouster_capture(tmp_path, "other", json_mode, "RNG19_RFL8_SIG16_NIR16", frames=1)
    shutil.copy(tmp_path / "other.json", tmp_path / "cap.json")
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    text = one_line(exc, path)
    cols = int(capture_mode.split("x")[0])
    assert f"0..{cols - 1}" in text and f"lidar_mode {json_mode}" in text and "--meta" in text


def test_a_hesai_capture_says_what_it_is(tmp_path):
    """A Hesai capture (``0xEEFF`` packets) is an error that names Hesai and how to convert it, with or without
    a json beside it; Ouster and Velodyne captures are not affected."""
    from data_tools.formats.ouster_pcap import OusterPcapSequence

    pandar40p = [b"\xee\xff" + bytes(1260)] * 40
    gps = [b"$GPRMC" + bytes(506)] * 10  # Hesai GPS packets between the data
    payloads = pandar40p[:20] + gps + pandar40p[20:]
    path = write_pcap(tmp_path / "hesai.pcap", payloads, [1e9 + k * 1e-4 for k in range(len(payloads))])
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    assert "Hesai lidar packets (1262 bytes" in one_line(exc, path) and "PointCloud2" in str(exc.value)
    (tmp_path / "hesai.json").write_text("{}")
    with pytest.raises(DataError, match="Hesai lidar packets") as exc:
        OusterPcapSequence(path)
    other = write_pcap(tmp_path / "robosense.pcap", [bytes(1248)] * 20, [1e9 + k * 1e-4 for k in range(20)], port=6699)
    with pytest.raises(DataError) as exc:
        open_dataset(other)
    assert "port 6699: 20 of 1248 bytes" in one_line(exc, other)
