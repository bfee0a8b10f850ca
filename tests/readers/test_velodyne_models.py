"""Velodyne models other than the VLP-16 (VLP-32C, HDL-32E, VLS-128) and the VLP-16 at other speeds,
from the packets' bytes; a model named other than the packets' factory byte is a one-line error.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from tests.inputs.velodyne import velodyne32_stream, vlp16_stream, write_pcap
from tests.messages import one_line


def vls128_stream(n_sweeps: float = 1.2):
    """VLS-128 data packets: 3 firing groups of 4 blocks (flags 0xFFEE, 0xFFDD, 0xFFCC, 0xFFBB for
    lasers 0-31, 32-63, 64-95, 96-127), all at 10 m."""
    group_dt = 53.3e-6
    groups = int(n_sweeps * 0.1 / group_dt) // 3 * 3
    flags = [b"\xff\xee", b"\xff\xdd", b"\xff\xcc", b"\xff\xbb"]
    payloads, stamps = [], []
    for g0 in range(0, groups, 3):
        buf = bytearray()
        for g in range(g0, g0 + 3):
            az = (g * group_dt * 3600.0 + 10.0) % 360.0
            for flag in flags:
                buf += flag + struct.pack("<H", round(az * 100) % 36000) + struct.pack("<HB", 2500, 80) * 32
        buf += struct.pack("<IBB", int(g0 * group_dt * 1e6), 0x37, 0xA1)
        payloads.append(bytes(buf))
        stamps.append(1.0e9 + g0 * group_dt)
    return payloads, stamps


@pytest.mark.parametrize(
    "model, options, rows",
    [
        ("VLP32C", {"factory": 0x28}, 32),
        ("HDL32E", {"factory": 0x21, "unit": 0.002}, 32),
        ("VLP32C", {"factory": 0x28, "dual": True}, 32),
        ("VLS128", {}, 128),
    ],
    ids=["vlp32c", "hdl32e", "vlp32c-dual", "vls128"],
)
def test_other_velodyne_models_give_one_row_per_laser(tmp_path, model, options, rows):
    """VLP-32C, HDL-32E and VLS-128 packets: the model from the factory byte, every laser a row, every decoded
    point kept (a dual return's last return shares its firing's slot), one sweep per revolution."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    stream = velodyne32_stream(**options) if options else vls128_stream()
    path = write_pcap(tmp_path / f"{model}.pcap", *stream)
    ds = open_dataset(path)
    assert ds.model == model
    pts = ds.sweep(0)[1]
    scan = ds[0]
    report = scan.meta["organize"]
    assert scan.shape[0] == rows and report["rings"] == rows and not report["warnings"]
    assert scan.n_points == len(pts) and np.unique(pts["ring"]).size == rows
    assert 0.095 < np.ptp(scan.point_times()) < 0.105
    r = np.linalg.norm(scan.points().astype(np.float64), axis=1)
    assert 7.9 < r.min() and r.max() < 14.1
    last = int((pts["return_type"] == 2).sum())  # velodyne_decoder ReturnMode.LAST
    assert scan.meta.get("second_returns", 0) == last and (last > 0.25 * len(pts)) == ("dual" in options)


@pytest.mark.parametrize("rpm, cols", [(300, 3600), (1200, 900)])
def test_vlp16_at_other_speeds_gives_one_column_per_firing(tmp_path, rpm, cols):
    """A VLP-16 at 300 and 1200 rpm gives sweeps of 60 / rpm seconds with one column per firing."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.2, rpm=rpm)
    ds = open_dataset(write_pcap(tmp_path / "v.pcap", payloads, stamps))
    scan = ds[1]
    assert scan.shape == (16, cols)
    np.testing.assert_allclose(np.diff(ds.times)[0], 60.0 / rpm, rtol=0.01)
    assert np.ptp(scan.point_times()) == pytest.approx(60.0 / rpm, rel=0.05)


def test_a_velodyne_model_other_than_the_packets_is_a_one_line_error(tmp_path):
    """``--model`` naming another Velodyne than the packets' factory byte is a one-line error naming both;
    models that share a packet format still read."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    path = write_pcap(tmp_path / "v32.pcap", *velodyne32_stream(0x28))
    with pytest.raises(DataError) as exc:
        open_dataset(path, model="VLP16")
    assert "--model VLP16" in one_line(exc, path) and "VLP32C (factory byte 0x28)" in str(exc.value)
    payloads, stamps, _ = vlp16_stream(n_sweeps=1.2)
    assert open_dataset(write_pcap(tmp_path / "v16.pcap", payloads, stamps), model="PuckLite").model == "PuckLite"
