"""Ouster pcap + json (ouster-sdk) and Velodyne pcap (velodyne-decoder) readers.

The Ouster checks run on the real captures in ../shared/data/ouster/pcaps against the decoded
``.npz`` of the same sweeps; the Velodyne checks on a VLP-16 capture written here packet by packet
from a known scene, so every decoded point's beam, azimuth and range are known.
"""

from __future__ import annotations

import logging
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.formats.ouster import read_ouster_npz
from data_tools.formats.ouster_pcap import OusterPcapSequence, find_metadata
from prc_slam.config import PRCConfig
from prc_slam.prc import classify_scan
from tests.conftest import SHARED_DATA
from tests.inputs.velodyne import FIRING, VLP16_ELEVATION, vlp16_stream, write_pcap

PCAPS = SHARED_DATA / "ouster" / "pcaps"
DECODED = SHARED_DATA / "ouster" / "decoded"


@pytest.fixture(scope="module")
def pcap_files() -> list[Path]:
    files = sorted(PCAPS.glob("*.pcap"))
    if not files or not sorted(DECODED.glob("*.npz")):
        pytest.skip(f"Ouster captures not found in {PCAPS} (or decoded sweeps in {DECODED})")
    return files


def decoded_by_frame_id() -> dict[tuple[str, int], Path]:
    """Decoded sweeps keyed by (sensor prefix, frame id), from names like ``OS-0-128_frame0_id1491.npz``."""
    out = {}
    for f in DECODED.glob("*.npz"):
        m = re.match(r"(OS-\d)-128.*_id(\d+)\.npz$", f.name)
        assert m, f.name
        out[(m.group(1), int(m.group(2)))] = f
    return out


def test_every_sweep_decoded_identical_to_npz(pcap_files):
    """Acceptance: every sweep decoded; xyz vs xyz_lidar_m <= 1 cm (p99); same ranges, times,
    reflectivity; PRC labels identical to those from the decoded npz."""
    decoded = decoded_by_frame_id()
    matched = 0
    cfg = PRCConfig.preset("multibeam")
    for pcap in pcap_files:
        seq = open_dataset(pcap)
        assert isinstance(seq, OusterPcapSequence)
        prefix = pcap.name[:4]
        expected = sorted(fid for (p, fid) in decoded if p == prefix)
        assert sorted(seq.frame_ids.tolist()) == expected, pcap.name  # every sweep, no extra or missing
        for i, scan in enumerate(seq):
            ref = read_ouster_npz(decoded[(prefix, int(seq.frame_ids[i]))])
            assert scan.meta["missing_columns"] == 0
            np.testing.assert_array_equal(scan.ranges, ref.ranges)
            np.testing.assert_array_equal(scan.timestamps, ref.timestamps)
            np.testing.assert_array_equal(scan.intensity, ref.intensity)
            valid = ref.ranges > 0
            err = np.linalg.norm(scan.xyz[valid] - ref.xyz[valid], axis=1)
            assert np.percentile(err, 99) <= 0.01, pcap.name
            np.testing.assert_array_equal(classify_scan(scan, cfg), classify_scan(ref, cfg))
            matched += 1
    assert matched == len(decoded)


def test_frame_times_and_random_access(pcap_files):
    lb = next((f for f in pcap_files if "lb_n3" in f.name), None)
    if lb is None:
        pytest.skip("the 3-sweep OS-1 capture is absent")
    seq = OusterPcapSequence(lb)
    assert len(seq) == 3
    assert seq.times is not None and np.allclose(np.diff(seq.times), 0.1, atol=0.002)  # 10 Hz
    forward = [seq[i].ranges for i in range(3)]
    np.testing.assert_array_equal(seq[0].ranges, forward[0])  # going back reopens the capture
    np.testing.assert_array_equal(seq[-1].ranges, forward[2])
    assert not np.array_equal(forward[0], forward[1])
    with pytest.raises(IndexError):
        seq[3]


def test_metadata_found_by_prefix(pcap_files):
    lb = next((f for f in pcap_files if "lb_n3" in f.name), None)
    if lb is None:
        pytest.skip("the 3-sweep OS-1 capture is absent")
    # OS-1-128_v2.3.0_1024x10_lb_n3.pcap is described by OS-1-128_v2.3.0_1024x10.json
    assert find_metadata(lb).name == "OS-1-128_v2.3.0_1024x10.json"


def test_destaggered_pcap_matches_destaggered_npz(pcap_files):
    seq = OusterPcapSequence(pcap_files[0], destaggered=True)
    prefix = pcap_files[0].name[:4]
    ref = read_ouster_npz(decoded_by_frame_id()[(prefix, int(seq.frame_ids[0]))], destaggered=True)
    np.testing.assert_array_equal(seq[0].ranges, ref.ranges)


def _one_line_error(exc: pytest.ExceptionInfo, path: Path) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_pcap_without_json_is_a_one_line_error(pcap_files, tmp_path):
    lone = tmp_path / "capture.pcap"
    lone.symlink_to(pcap_files[0])
    with pytest.raises(DataError) as exc:
        open_dataset(lone)
    assert "capture.json" in _one_line_error(exc, lone)
    with pytest.raises(DataError) as exc:
        OusterPcapSequence(lone, meta=tmp_path / "nope.json")
    assert "nope.json" in _one_line_error(exc, lone)


def test_bad_or_foreign_metadata(pcap_files, tmp_path):
    pcap = tmp_path / "x.pcap"
    pcap.symlink_to(pcap_files[0])
    (tmp_path / "x.json").write_text('{"not": "ouster"}')
    with pytest.raises(DataError, match="cannot use sensor metadata") as exc:
        OusterPcapSequence(pcap)
    _one_line_error(exc, pcap)
    # another sensor's metadata: the packets' init id / serial do not match
    others = [f for f in PCAPS.glob("*.json") if not pcap_files[0].name.startswith(f.stem)]
    (tmp_path / "x.json").write_text(others[0].read_text())
    with pytest.raises(DataError, match="no lidar packets matching") as exc:
        OusterPcapSequence(pcap)
    _one_line_error(exc, pcap)


def test_truncated_capture_reports_missing_columns(pcap_files, tmp_path, caplog):
    lb = next((f for f in pcap_files if "lb_n3" in f.name), None)
    if lb is None:
        pytest.skip("the 3-sweep OS-1 capture is absent")
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(lb.read_bytes()[:1_000_000])  # about 1.6 of the 3 sweeps, cut inside a packet
    (tmp_path / "cut.json").write_text(find_metadata(lb).read_text())
    seq = OusterPcapSequence(cut, destaggered=False)  # measurement columns: the columns the packets carry
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        scans = list(seq)
    assert len(scans) == 2
    assert scans[0].meta["missing_columns"] == 0
    missing = scans[1].meta["missing_columns"]
    assert 0 < missing < 1024
    assert any("columns missing" in r.message for r in caplog.records)
    # the missing columns hold no return, the received ones the same data as the full capture
    full = OusterPcapSequence(lb, destaggered=False)[1]
    got = scans[1].ranges.any(axis=0)
    np.testing.assert_array_equal(scans[1].ranges[:, got], full.ranges[:, got])
    assert int((~got).sum()) >= missing


# --- Velodyne -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def vlp16_capture(tmp_path_factory):
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, truth = vlp16_stream()
    path = write_pcap(tmp_path_factory.mktemp("vlp16") / "vlp16.pcap", payloads, stamps)
    return path, truth


def test_velodyne_pcap_detected_and_decoded(vlp16_capture):
    path, truth = vlp16_capture
    ds = open_dataset(path)
    assert ds.format == "velodyne-pcap" and ds.model == "VLP16"
    returns = truth[truth[:, 3] > 0]
    sweeps = [ds.sweep(i)[1] for i in range(len(ds))]
    assert len(ds) == 3  # 2.3 revolutions: two whole sweeps and the rest
    pts = np.concatenate(sweeps)
    assert len(pts) == len(returns)  # every return decoded, in firing order
    xyz = np.column_stack([pts["x"], pts["y"], pts["z"]]).astype(np.float64)
    r = np.linalg.norm(xyz, axis=1)
    assert np.abs(r - returns[:, 3]).max() < 0.005  # 2 mm range resolution
    elevation = np.degrees(np.arcsin(xyz[:, 2] / r))
    assert np.abs(elevation - VLP16_ELEVATION[returns[:, 2].astype(int)]).max() < 0.2


def test_velodyne_pcap_organised_into_true_slots(vlp16_capture):
    """Each sweep through the organiser: one row per beam (top beam first), columns in firing
    order; every decoded point gets one label back."""
    path, truth = vlp16_capture
    ds = open_dataset(path)
    returns = truth[truth[:, 3] > 0]
    beam_row = np.argsort(np.argsort(-VLP16_ELEVATION))  # laser id -> row, top beam first
    start = 0
    cfg = PRCConfig.preset("multibeam")
    for i in range(2):  # the two whole sweeps
        scan = ds[i]
        n = scan.n_points
        t = returns[start : start + n]
        start += n
        report = scan.meta["organize"]
        assert scan.shape[0] == 16 and report["rings"] == 16 and report["method"] == "ring-field"
        row = scan.point_slot // scan.shape[1]
        assert (row == beam_row[t[:, 2].astype(int)]).mean() == 1.0
        # each point sits in the column whose azimuth (sensor model) is its own, within one column
        xyz = scan.points().astype(np.float64)
        slot_az = scan.sensor.azimuth().ravel()[scan.point_slot]
        gap = np.angle(np.exp(1j * (np.arctan2(xyz[:, 1], xyz[:, 0]) - slot_az)))
        assert (np.abs(gap) <= 2 * np.pi / scan.shape[1]).mean() >= 0.99
        labels = scan.per_point(classify_scan(scan, cfg))
        assert labels.shape == (n,)
        assert scan.point_times() is not None and np.ptp(scan.point_times()) < 0.11


def test_velodyne_pcap_bad_input(tmp_path):
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    from data_tools.formats.velodyne_pcap import VelodynePcapSequence

    payloads, stamps, _ = vlp16_stream(n_sweeps=0.5)
    path = write_pcap(tmp_path / "v.pcap", payloads, stamps)
    with pytest.raises(DataError, match="unknown Velodyne model 'VLP99'") as exc:
        VelodynePcapSequence(path, model="VLP99")
    _one_line_error(exc, path)
    empty = write_pcap(tmp_path / "empty.pcap", [], [])
    with pytest.raises(DataError) as exc:  # neither Velodyne packets nor an Ouster json
        open_dataset(empty)
    _one_line_error(exc, empty)


def test_missing_range_channel_is_a_clear_error(pcap_files):
    # single-return profiles have no second-return channel
    with pytest.raises(DataError, match="has no RANGE2 channel") as exc:
        OusterPcapSequence(pcap_files[0], field="RANGE2")
    _one_line_error(exc, pcap_files[0])


def vlp16_dual_stream(n_sweeps: float = 1.3, rpm: float = 600.0):
    """A VLP-16 in dual-return mode (0x39): blocks in pairs at one azimuth, last return first,
    then the strongest. On every third laser the last return lies 2 m behind the strongest
    (e.g. through foliage); elsewhere both are the same (decoded once, as BOTH)."""
    deg_per_s = rpm / 60.0 * 360.0
    pair_dt = 2 * FIRING
    pairs = int(n_sweeps * 60.0 / rpm / pair_dt) // 6 * 6
    payloads, stamps = [], []
    for p0 in range(0, pairs, 6):
        buf = bytearray()
        for j in range(p0, p0 + 6):
            az = (j * pair_dt * deg_per_s + 10.0) % 360.0
            for last in (True, False):
                buf += b"\xff\xee" + struct.pack("<H", round(az * 100) % 36000)
                for _ in range(2):
                    for k in range(16):
                        r = 12.0 if last and k % 3 == 0 else 10.0
                        buf += struct.pack("<HB", int(r / 0.002), 50 if last else 100)
        buf += struct.pack("<IBB", int(p0 * pair_dt * 1e6), 0x39, 0x22)
        payloads.append(bytes(buf))
        stamps.append(1.0e9 + p0 * pair_dt)
    return payloads, stamps


def test_velodyne_dual_return_shares_slots(tmp_path):
    """Dual return: the range image holds one return per firing (the strongest); the last
    return of the same firing shares its slot and label, and does not count as a collision."""
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    path = write_pcap(tmp_path / "dual.pcap", *vlp16_dual_stream())
    ds = open_dataset(path)
    pts = ds.sweep(0)[1]
    scan = ds[0]
    n = len(pts)
    assert scan.n_points == n and scan.points().shape == (n, 3)
    last = pts["return_type"] == 2
    assert last.sum() == scan.meta["second_returns"] > 0.2 * n
    assert scan.meta["organize"]["collisions_pct"] < 5.0 and not scan.meta["organize"]["warnings"]
    key = pts["column"].astype(np.int64) * 4096 + pts["ring"]
    strongest = ~last
    partner = dict(zip(key[strongest].tolist(), np.flatnonzero(strongest).tolist(), strict=True))
    partner_of_last = np.array([partner[k] for k in key[last].tolist()])
    np.testing.assert_array_equal(scan.point_slot[last], scan.point_slot[partner_of_last])
    # the image holds the strongest returns (10 m), never the last ones (12 m)
    held = scan.ranges.ravel()[scan.point_slot[last]]
    assert np.abs(held - 10.0).max() < 0.01
    labels = scan.per_point(classify_scan(scan, PRCConfig.preset("multibeam")))
    assert labels.shape == (n,)
    np.testing.assert_array_equal(labels[last], labels[partner_of_last])


def test_primary_returns_hand_computed():
    from data_tools.formats.velodyne_pcap import primary_returns

    # firing (column 0, ring 0): LAST then STRONGEST -> the strongest is kept, the last shares it;
    # (0, 1): BOTH; (1, 0): a LAST return alone is kept
    primary, partner = primary_returns(np.array([0, 0, 1, 0]), np.array([0, 0, 0, 1]), np.array([2, 1, 3, 2]))
    np.testing.assert_array_equal(primary, [False, True, True, True])
    np.testing.assert_array_equal(partner, [1, 1, 2, 3])
