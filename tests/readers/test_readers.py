"""KITTI and Ouster readers: organisation through the organiser, point-to-slot mapping, and bad input."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.formats.kitti import KittiSequence, read_calib_tr, read_label_file, read_velodyne_bin
from data_tools.formats.ouster import destagger, read_ouster_npz
from prc_slam import labels as L
from tests.inputs.kitti import CALIB, make_kitti, synthetic_sweep


def test_kitti_bins_organised_ring_by_ring(tmp_path):
    """The organiser finds the 8 rings (top beam first) and the 360 firings of a ring-major bin."""
    pts, ring, col = synthetic_sweep(with_rings=True)
    root = tmp_path / "seq"
    (root / "velodyne").mkdir(parents=True)
    pts.tofile(root / "velodyne" / "000000.bin")
    scan = KittiSequence(root)[0]
    rep = scan.meta["organize"]
    assert (rep["method"], rep["rings"], rep["cols"], rep["collisions_pct"]) == ("ring-major", 8, 360, 0.0)
    row, c = np.divmod(scan.point_slot, scan.shape[1])
    np.testing.assert_array_equal(row, 7 - ring)  # ring 7 is the highest beam
    # one column per firing, up to a constant shift and the direction (without a time convention
    # the columns follow the point order)
    shifts = [(c + col) % 360, (c - col) % 360]
    assert any(np.all(shift == shift[0]) for shift in shifts)
    assert scan.timestamps is None  # KITTI bins are motion-compensated: no made-up times
    np.testing.assert_allclose(np.degrees(scan.sensor.altitude), -20 + 2.5 * np.arange(8)[::-1], atol=1e-3)


def test_kitti_rings_with_jitter_around_the_cut(tmp_path):
    """Points just either side of azimuth 0 in the middle of a ring do not start a new ring."""
    pts, ring, _ = synthetic_sweep(rings=3, with_rings=True)
    i = int(np.flatnonzero(ring == 1)[100])
    jitter = np.array([[10, -0.001, 0, 0], [10, 0.001, 0, 0]], np.float32)
    jitter[:, 2] = 10 * np.tan(np.radians(-20 + 2.5))  # ring 1's elevation
    pts = np.concatenate([pts[:i], jitter, pts[i:]])
    ring = np.concatenate([ring[:i], [1, 1], ring[i:]])
    root = tmp_path / "seq"
    (root / "velodyne").mkdir(parents=True)
    pts.tofile(root / "velodyne" / "000000.bin")
    scan = KittiSequence(root)[0]
    assert scan.meta["organize"]["rings"] == 3
    np.testing.assert_array_equal(scan.point_slot // scan.shape[1], 2 - ring)


def test_kitti_slots_hold_their_nearest_point(tmp_path):
    root = make_kitti(tmp_path / "seq", frames=1)
    pts = read_velodyne_bin(root / "velodyne" / "000000.bin")
    scan = KittiSequence(root, cols=300)[0]  # fewer columns than firings: slots are shared
    assert scan.point_slot.shape == (len(pts),)
    assert scan.valid.sum() + scan.meta["collisions"] == len(pts)
    rng = np.linalg.norm(pts[:, :3], axis=1)
    flat = scan.ranges.ravel()
    for slot in np.unique(scan.point_slot)[:80]:
        members = np.flatnonzero(scan.point_slot == slot)
        assert flat[slot] == pytest.approx(rng[members].min())
    shared = np.bincount(scan.point_slot) > 1
    assert shared.any()
    assert scan.meta["organize"]["collisions_pct"] == pytest.approx(100 * scan.meta["collisions"] / len(pts))


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


def test_nan_in_bin(tmp_path, caplog):
    """NaN rows are no-return points: counted, warned about, label 0, every other point kept."""
    root = make_kitti(tmp_path / "seq", frames=1)
    f = root / "velodyne" / "000000.bin"
    pts = read_velodyne_bin(f)
    pts[5, 1] = np.nan
    pts.tofile(f)
    with pytest.raises(DataError, match=r"NaN or infinite.*index 5"):
        read_velodyne_bin(f)
    with caplog.at_level(logging.WARNING, logger="prc_slam.organize"):
        scan = KittiSequence(root)[0]
    assert scan.meta["organize"]["nonfinite_points"] == 1
    assert "1 of 2012 points have no return" in caplog.text
    assert scan.n_points == len(pts) and np.isfinite(scan.points()).all()
    codes = scan.per_point(np.full(scan.shape, L.VEGETATION, np.uint8) * scan.valid)
    assert codes[5] == L.NO_RETURN and (np.delete(codes, 5) == L.VEGETATION).all()


def test_label_count_mismatch(tmp_path, caplog):
    root = make_kitti(tmp_path / "seq", frames=1)
    lab = root / "labels" / "000000.label"
    lab.write_bytes(lab.read_bytes()[:-8])
    with pytest.raises(DataError, match=r"000000.label: 2010 labels for 2012 points"):
        read_label_file(lab, 2012)
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):  # the frame is read, not scored
        scan = KittiSequence(root)[0]
    assert scan.gt_labels is None and "000000.label: 2010 labels for 2012 points" in caplog.text
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
    with pytest.raises(DataError, match="line 1: 3 values, expected 12"):
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


def test_every_format_has_one_reader_in_the_registry():
    """``--format`` names and the registry agree: each format is opened by exactly one reader, and
    each reader's options are what ``open_dataset`` checks the given options against."""
    from data_tools.datasets import FORMAT_ALIASES, FORMATS, readers

    names = [r.format for r in readers()]
    assert sorted(names) == sorted(FORMATS) and len(set(names)) == len(names)
    assert set(FORMAT_ALIASES.values()) <= set(FORMATS)
    assert all(isinstance(r.options, tuple) for r in readers())


def test_the_first_reader_that_recognises_an_input_opens_it(tmp_path):
    """A folder that is a simulated sequence and also holds sweep files is the simulated sequence
    (the registry's order), and a folder of sweeps forced to another format gets that reader's error."""
    from data_tools.datasets import detect_format

    root = tmp_path / "seq"
    (root / "velodyne").mkdir(parents=True)
    (root / "000000.pcd").write_text("")
    assert detect_format(root) == "kitti"  # the KITTI directory comes before the folder of sweeps
    (root / "sim.json").write_text("{}")
    assert detect_format(root) == "sim"
    with pytest.raises(DataError, match="--topic does not apply to sim input"):
        open_dataset(root, topic="/points")
    with pytest.raises(DataError, match="unsupported format 'nope'"):
        open_dataset(root, "nope")


def test_organiser_hints_from_reader_options():
    from data_tools.sequence import organiser_hints

    assert organiser_hints({}) == {"rows": None, "cols": None, "method": "auto"}
    assert organiser_hints({"rows": "64", "cols": 2048, "organize_method": "beams"}) == {
        "rows": 64,
        "cols": 2048,
        "method": "beams",
    }


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
    scan = read_ouster_npz(f, destaggered=False)
    raw = np.load(f)
    np.testing.assert_allclose(scan.ranges, raw["range_mm"] / 1000.0, rtol=1e-6)
    d = read_ouster_npz(f)  # destaggered by default
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
