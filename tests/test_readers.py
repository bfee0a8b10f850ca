"""KITTI and Ouster readers: unfolding, point-to-slot mapping, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.kitti import KittiSequence, read_calib_tr, read_label_file, read_velodyne_bin, ring_index, unfold_scan
from data_tools.ouster import destagger, read_ouster_npz
from prc_slam import labels as L

CALIB = "Tr: " + " ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"]) + "\n"


def synthetic_sweep(rings: int = 8, per_ring: int = 200, seed: int = 0) -> np.ndarray:
    """Points ring by ring, azimuth increasing from 0 through ±pi, like a KITTI bin."""
    rng = np.random.default_rng(seed)
    pts = []
    for k in range(rings):
        az = np.sort(rng.uniform(0.01, 2 * np.pi - 0.05, per_ring))
        el = np.radians(-20 + 2.5 * k)
        r = rng.uniform(5, 30, per_ring)
        x, y, z = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el) * np.ones(per_ring)
        pts.append(np.stack([x, y, z, rng.random(per_ring)], axis=1))
    return np.concatenate(pts).astype(np.float32)


def make_kitti(root: Path, frames: int = 2, labels: bool = True) -> Path:
    (root / "velodyne").mkdir(parents=True)
    for i in range(frames):
        pts = synthetic_sweep(seed=i)
        pts.tofile(root / "velodyne" / f"{i:06d}.bin")
        if labels:
            (root / "labels").mkdir(exist_ok=True)
            sem = np.where(pts[:, 2] < -3, 40, 50).astype(np.uint32) | (np.uint32(7) << 16)
            sem.tofile(root / "labels" / f"{i:06d}.label")
    (root / "calib.txt").write_text(CALIB)
    (root / "times.txt").write_text("".join(f"{0.1 * i:e}\n" for i in range(frames)))
    pose = "1 0 0 {x} 0 1 0 0 0 0 1 0\n"
    (root / "poses.txt").write_text("".join(pose.format(x=i) for i in range(frames)))
    return root


def test_ring_index_recovers_rings():
    pts = synthetic_sweep(rings=8)
    ring = ring_index(pts[:, :3], 64)
    np.testing.assert_array_equal(ring, np.repeat(np.arange(8), 200))


def test_ring_index_ignores_jitter_around_zero_azimuth():
    pts = synthetic_sweep(rings=3)
    # insert a point just below azimuth 0 in the middle of ring 1 before one just above it
    jitter = np.array([[10, -0.001, 0, 0], [10, 0.001, 0, 0]], np.float32)
    pts = np.concatenate([pts[:250], jitter, pts[250:]])
    ring = ring_index(pts[:, :3], 64)
    assert ring.max() == 2


def test_unfold_maps_every_point_to_exactly_one_slot():
    pts = synthetic_sweep()
    un = unfold_scan(pts, rows=64, cols=512)
    assert un.point_slot.shape == (len(pts),)
    assert un.ranges.shape == (64, 512)
    filled = un.representative >= 0
    assert filled.sum() + un.collisions == len(pts)
    # the representative is the nearest point of its slot
    rng = np.linalg.norm(pts[:, :3], axis=1)
    for slot in np.flatnonzero(filled)[:50]:
        members = np.flatnonzero(un.point_slot == slot)
        assert un.representative[slot] == members[np.argmin(rng[members])]
        assert un.ranges.ravel()[slot] == pytest.approx(rng[members].min())
    np.testing.assert_allclose(np.degrees(un.altitude[:8]), -20 + 2.5 * np.arange(8), atol=1e-3)


def test_kitti_sequence_roundtrip(tmp_path):
    root = make_kitti(tmp_path / "seq")
    ds = open_dataset(root)
    assert isinstance(ds, KittiSequence) and len(ds) == 2
    scan = ds[1]
    pts = read_velodyne_bin(root / "velodyne" / "000001.bin")
    assert scan.n_points == len(pts)
    np.testing.assert_array_equal(scan.points(), pts[:, :3])
    ref = scan.reference_labels()
    assert ref.shape == (len(pts),)
    assert set(np.unique(ref)) <= {L.GROUND, L.BUILDING}
    codes = scan.per_point(np.full(scan.shape, L.VEGETATION, np.uint8))
    assert codes.shape == (len(pts),)
    np.testing.assert_allclose(ds.poses[1][:3, 3], [1, 0, 0])


def test_truncated_bin(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=1)
    f = root / "velodyne" / "000000.bin"
    f.write_bytes(f.read_bytes()[:-6])
    with pytest.raises(DataError, match=r"000000.bin: truncated"):
        KittiSequence(root)[0]


def test_nan_in_bin(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=1)
    f = root / "velodyne" / "000000.bin"
    pts = read_velodyne_bin(f)
    pts[5, 1] = np.nan
    pts.tofile(f)
    with pytest.raises(DataError, match=r"NaN or infinite.*index 5"):
        KittiSequence(root)[0]


def test_label_count_mismatch(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=1)
    lab = root / "labels" / "000000.label"
    lab.write_bytes(lab.read_bytes()[:-8])
    with pytest.raises(DataError, match=r"000000.label: 1598 labels for 1600 points"):
        KittiSequence(root)[0]
    lab.write_bytes(lab.read_bytes()[:-1])
    with pytest.raises(DataError, match="truncated"):
        read_label_file(lab)


def test_missing_calib_and_bad_poses(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=1)
    (root / "calib.txt").unlink()
    with pytest.raises(DataError, match=r"calib.txt is missing"):
        KittiSequence(root)
    (root / "calib.txt").write_text("Tr: 1 2 3\n")
    with pytest.raises(DataError, match="Tr has 3 values"):
        read_calib_tr(root / "calib.txt")
    (root / "calib.txt").write_text(CALIB)
    (root / "poses.txt").write_text("1 0 0\n")
    with pytest.raises(DataError, match="3 values per line"):
        KittiSequence(root)


def test_non_monotonic_times(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=2)
    (root / "times.txt").write_text("0.2\n0.1\n")
    with pytest.raises(DataError, match="not strictly increasing"):
        KittiSequence(root)


def test_unknown_format(tmp_path):
    with pytest.raises(DataError, match="unknown input format"):
        open_dataset(tmp_path)
    with pytest.raises(DataError, match="no such file"):
        open_dataset(tmp_path / "nope")


def make_ouster(path: Path, rows: int = 8, cols: int = 32, **override) -> Path:
    rng = np.random.default_rng(0)
    data = {
        "range_mm": rng.integers(500, 20000, (rows, cols)).astype(np.uint32),
        "reflectivity": rng.integers(0, 255, (rows, cols)).astype(np.uint8),
        "column_ts_ns": (np.arange(cols) * 97_656 + 10**12).astype(np.uint64),
        "column_valid": np.ones(cols, bool),
        "beam_altitude_deg": np.linspace(20, -20, rows),
        "beam_azimuth_deg": np.tile([4.2, 1.4, -1.4, -4.2], rows // 4),
        "pixel_shift_by_row": np.tile([3, 2, 1, 0], rows // 4).astype(np.int64),
    }
    data.update(override)
    np.savez(path, **data)
    return path


def test_ouster_reader_and_destagger(tmp_path):
    f = make_ouster(tmp_path / "a.npz")
    scan = read_ouster_npz(f)
    raw = np.load(f)
    np.testing.assert_allclose(scan.ranges, raw["range_mm"] / 1000.0, rtol=1e-6)
    d = read_ouster_npz(f, destaggered=True)
    np.testing.assert_array_equal(d.ranges[0], np.roll(scan.ranges[0], 3))
    np.testing.assert_array_equal(d.ranges[3], scan.ranges[3])
    # destaggering does not change where a measurement points
    xyz_s = scan.sensor.to_xyz(scan.ranges)
    xyz_d = d.sensor.to_xyz(d.ranges)
    np.testing.assert_allclose(destagger(xyz_s, raw["pixel_shift_by_row"]), xyz_d, atol=1e-4)
    assert scan.slot_times().shape == scan.shape


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"range_mm": np.zeros(5, np.uint32)}, "must be 2-D"),
        ({"beam_altitude_deg": np.zeros(3)}, "beam_altitude_deg has shape"),
        ({"column_ts_ns": np.arange(32)[::-1].astype(np.uint64)}, "not monotonic"),
    ],
)
def test_ouster_bad_input(tmp_path, override, message):
    f = make_ouster(tmp_path / "bad.npz", **override)
    with pytest.raises(DataError, match=message):
        read_ouster_npz(f)


def test_ouster_missing_array_and_garbage(tmp_path):
    f = tmp_path / "m.npz"
    np.savez(f, range_mm=np.zeros((2, 2), np.uint32))
    with pytest.raises(DataError, match="missing arrays"):
        read_ouster_npz(f)
    g = tmp_path / "g.npz"
    g.write_bytes(b"not a zip")
    with pytest.raises(DataError, match=r"g.npz: cannot read"):
        read_ouster_npz(g)
