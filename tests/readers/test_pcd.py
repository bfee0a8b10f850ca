"""Folders of PCD / PLY / bin sweeps and single sweep files: readers, the PCD writer, organising."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.formats.pcd import (
    SweepFolder,
    read_pcd,
    read_ply,
    times_in_seconds,
    write_pcd,
)
from data_tools.formats.writers import write_las, write_ply
from prc_slam.config import PRCConfig
from prc_slam.prc import classify_scan
from tests.conftest import SHARED_DATA
from tests.messages import one_line

MULTISENSOR = SHARED_DATA / "multisensor"
ELEVATION_DEG = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15], float)


def room_sweep(cols: int = 900, dropout: float = 0.05, seed: int = 0, layout: str = "firing"):
    """A simulated 16-beam sweep in a round room (walls 10-20 m, floor 1.8 m below).

    Returns fields (x y z intensity ring t) in the driver's order and the true (row, col) of
    every point (row 0 = top beam). ``layout`` "firing": all beams of one azimuth, then the
    next (Velodyne driver); "ring": one beam's revolution after the other.
    """
    rng = np.random.default_rng(seed)
    laser, c = np.meshgrid(np.arange(16), np.arange(cols), indexing="ij")
    if layout == "firing":
        laser, c = laser.T, c.T
    laser, c = laser.ravel(), c.ravel()
    az = 2 * np.pi * (c + 0.5) / cols
    el = np.radians(ELEVATION_DEG[laser])
    r = (15.0 + 5.0 * np.sin(3.0 * az)) / np.cos(el)
    r = np.minimum(r, np.where(el < 0, 1.8 / np.maximum(-np.sin(el), 1e-9), np.inf))
    keep = rng.random(r.size) >= dropout
    laser, c, az, el, r = laser[keep], c[keep], az[keep], el[keep], r[keep]
    xyz = np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)])
    row = np.argsort(np.argsort(-ELEVATION_DEG))[laser]
    fields = {
        "x": xyz[:, 0].astype(np.float32),
        "y": xyz[:, 1].astype(np.float32),
        "z": xyz[:, 2].astype(np.float32),
        "intensity": rng.integers(0, 255, len(r)).astype(np.uint8),
        "ring": laser.astype(np.uint16),  # the driver's numbering: laser id, not row
        "t": (c * 0.1 / cols * 1e9).astype(np.uint32),  # ns since the sweep start (Ouster/Livox style)
    }
    return fields, row, c


def slot_accuracy(scan, row_true: np.ndarray, col_true: np.ndarray) -> float:
    """Share of points in their true row and in the column of their true azimuth (one constant
    column shift allowed: where column 0 starts is the organiser's choice)."""
    row, col = np.divmod(scan.point_slot, scan.shape[1])
    shift = np.bincount(np.mod(col - col_true, scan.shape[1])).argmax()
    return float(((row == row_true) & (np.mod(col - col_true, scan.shape[1]) == shift)).mean())


# ----------------------------------------------------------------------------- PCD reader/writer

ASCII_PCD = """# .PCD v0.7 - Point Cloud Data file format
VERSION 0.7
FIELDS x y z rgb ring normal
SIZE 4 4 8 4 2 4
TYPE F F F U U F
COUNT 1 1 1 1 1 3
WIDTH 3
HEIGHT 1
VIEWPOINT 0 0 0 1 0 0 0
POINTS 3
DATA ascii
1.5 -2 3.25 4278190080 7 0 0 1
nan 0 1e2 0 65535 0.5 0.5 0
-1 -1 -1 1 0 1 0 0
"""


def test_pcd_ascii_hand_made(tmp_path):
    f = tmp_path / "a.pcd"
    f.write_text(ASCII_PCD)
    fields, hw = read_pcd(f)
    assert hw == (1, 3)
    assert list(fields) == ["x", "y", "z", "rgb", "ring", "normal"]
    assert fields["z"].dtype == np.float64 and fields["ring"].dtype == np.uint16 and fields["rgb"].dtype == np.uint32
    np.testing.assert_array_equal(fields["x"], np.array([1.5, np.nan, -1], np.float32))
    np.testing.assert_array_equal(fields["z"], [3.25, 100.0, -1.0])
    np.testing.assert_array_equal(fields["rgb"], [4278190080, 0, 1])
    np.testing.assert_array_equal(fields["ring"], [7, 65535, 0])
    np.testing.assert_array_equal(fields["normal"], [[0, 0, 1], [0.5, 0.5, 0], [1, 0, 0]])


def all_types_fields(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "x": rng.normal(0, 10, n).astype(np.float32),
        "y": rng.normal(0, 10, n).astype(np.float32),
        "z": rng.normal(0, 10, n).astype(np.float64),
        "h": rng.normal(0, 1, n).astype(np.float16),
        "i8": rng.integers(-128, 127, n).astype(np.int8),
        "u16": rng.integers(0, 65535, n).astype(np.uint16),
        "i32": rng.integers(-(2**31), 2**31 - 1, n).astype(np.int32),
        "u64": rng.integers(0, 2**62, n).astype(np.uint64),
        "normal": rng.normal(0, 1, (n, 3)).astype(np.float32),
        "label": rng.integers(0, 70, n).astype(np.uint8),
    }


def test_pcd_binary_round_trip_every_type(tmp_path):
    fields = all_types_fields(257)
    f = write_pcd(tmp_path / "b.pcd", fields)
    back, hw = read_pcd(f)
    assert hw == (1, 257) and list(back) == list(fields)
    for k, v in fields.items():
        assert back[k].dtype == v.dtype, k
        np.testing.assert_array_equal(back[k], v)


def write_compressed_pcd(path: Path, fields: dict[str, np.ndarray]) -> Path:
    """binary_compressed as PCL writes it: fields one after another (structure of arrays), LZF."""
    import lzf

    binary = read_pcd(write_pcd(path.with_suffix(".tmp.pcd"), fields))[0]
    soa = b"".join(np.ascontiguousarray(v).tobytes() for v in binary.values())
    header = path.with_suffix(".tmp.pcd").read_bytes().split(b"DATA binary\n")[0] + b"DATA binary_compressed\n"
    packed = lzf.compress(soa, 2 * len(soa) + 16) if soa else b""  # (room for incompressible data)
    path.write_bytes(header + np.array([len(packed), len(soa)], "<u4").tobytes() + packed)
    return path


def test_pcd_binary_compressed(tmp_path):
    fields = all_types_fields(100, seed=3)
    back, _ = read_pcd(write_compressed_pcd(tmp_path / "c.pcd", fields))
    for k, v in fields.items():
        np.testing.assert_array_equal(back[k], v)


def test_pcd_binary_compressed_corrupt_or_empty(tmp_path):
    """A damaged LZF stream is a one-line error naming the file; a compressed cloud of no points reads."""
    f = write_compressed_pcd(tmp_path / "c.pcd", all_types_fields(100, seed=3))
    raw = f.read_bytes()
    head = raw.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    f.write_bytes(raw[: head + 8] + b"\x80\x05" + raw[head + 10 :])  # a back reference before the start
    with pytest.raises(DataError, match="corrupt binary_compressed data") as exc:
        read_pcd(f)
    one_line(exc, f)
    empty = write_compressed_pcd(tmp_path / "e.pcd", {k: v[:0] for k, v in all_types_fields(3).items()})
    fields, hw = read_pcd(empty)
    assert hw == (1, 0) and all(len(v) == 0 for v in fields.values())


def test_pcd_binary_compressed_written_by_open3d(tmp_path):
    o3d = pytest.importorskip("open3d")
    xyz = np.random.default_rng(1).normal(0, 5, (5000, 3))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    o3d.io.write_point_cloud(str(tmp_path / "o.pcd"), pc, write_ascii=False, compressed=True)
    assert b"binary_compressed" in (tmp_path / "o.pcd").read_bytes()[:400]
    back, _ = read_pcd(tmp_path / "o.pcd")
    got = np.column_stack([back["x"], back["y"], back["z"]])
    np.testing.assert_allclose(got, xyz, atol=1e-5)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("TYPE F F F U U F", "TYPE F F F X U F", "unknown PCD type 'X'"),
        ("SIZE 4 4 8 4 2 4", "SIZE 4 4 8 3 2 4", "unknown PCD type 'U' of size 3"),
        ("DATA ascii", "DATA zipped", "unknown PCD DATA kind"),
        ("COUNT 1 1 1 1 1 3", "COUNT 1 1 1", "different lengths"),
        ("POINTS 3", "POINTS 4", "truncated"),
        ("FIELDS x y z rgb ring normal", "FIELDS a y z rgb ring normal", "no 'x' field"),
    ],
)
def test_pcd_bad_input_is_one_line(tmp_path, old, new, message):
    f = tmp_path / "bad.pcd"
    f.write_text(ASCII_PCD.replace(old, new).replace("WIDTH 3", "WIDTH 4" if "POINTS 4" in new else "WIDTH 3"))
    with pytest.raises(DataError, match=message) as exc:
        SweepFolder(f)[0]
    one_line(exc, f)


def test_pcd_truncated_binary(tmp_path):
    f = write_pcd(tmp_path / "t.pcd", all_types_fields(50))
    f.write_bytes(f.read_bytes()[:-7])
    with pytest.raises(DataError, match="truncated") as exc:
        read_pcd(f)
    one_line(exc, f)


def test_write_pcd_rejects_bad_fields(tmp_path):
    with pytest.raises(DataError, match="shape"):
        write_pcd(tmp_path / "a.pcd", {"x": np.zeros(3), "y": np.zeros(4)})
    with pytest.raises(DataError, match="field name"):
        write_pcd(tmp_path / "a.pcd", {"x y": np.zeros(3)})


# ----------------------------------------------------------------------------- PLY, times


def test_ply_binary_and_ascii(tmp_path):
    xyz = np.random.default_rng(0).normal(0, 3, (40, 3)).astype(np.float32)
    write_ply(tmp_path / "a.ply", xyz, np.arange(40) % 7)
    fields = read_ply(tmp_path / "a.ply")
    np.testing.assert_array_equal(np.column_stack([fields["x"], fields["y"], fields["z"]]), xyz)
    np.testing.assert_array_equal(fields["label"], np.arange(40) % 7)
    text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
    text += "property uchar ring\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    text += "1 2 3 4\n5 6 7 8\n3 0 1 1\n"
    (tmp_path / "b.ply").write_text(text)
    fields = read_ply(tmp_path / "b.ply")
    np.testing.assert_array_equal(fields["z"], [3, 7])
    np.testing.assert_array_equal(fields["ring"], [4, 8])
    (tmp_path / "c.ply").write_text(text.replace("property uchar ring", "property complex ring"))
    with pytest.raises(DataError, match="unknown PLY type 'complex'"):
        read_ply(tmp_path / "c.ply")


@pytest.mark.parametrize(
    ("values", "scale"),
    [
        (np.linspace(0, 0.099, 50), 1.0),  # Velodyne driver: s
        (np.linspace(1.7e9, 1.7e9 + 0.1, 50), 1.0),  # absolute s (Hesai)
        (np.linspace(0, 99_000_000, 50).astype(np.uint32), 1e-9),  # Ouster t: ns
        (np.linspace(0, 99_000, 50).astype(np.uint32), 1e-6),  # us
        (np.linspace(0, 99, 50), 1e-3),  # ms
    ],
)
def test_time_units(values, scale):
    t, got = times_in_seconds(values, "t", "x.pcd")
    assert got == scale
    assert np.ptp(t) == pytest.approx(np.ptp(values.astype(np.float64)) * scale)


# ----------------------------------------------------------------------------- folders


def test_folder_mixing_sweep_sizes(tmp_path):
    """Sweeps of different sizes (dropouts 2-30 %), ring and ns time fields, a times.txt: each
    sweep organised with >= 99 % of points in their true slot, one label per input point."""
    truths = []
    for i, dropout in enumerate((0.02, 0.3, 0.1)):
        fields, row, col = room_sweep(dropout=dropout, seed=i)
        order = np.random.default_rng(i).permutation(len(row)) if i == 2 else np.arange(len(row))  # any order
        write_pcd(tmp_path / f"{i:06d}.pcd", {k: v[order] for k, v in fields.items()})
        truths.append((row[order], col[order]))
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.2\n")
    ds = open_dataset(tmp_path)
    assert ds.format == "pcd" and len(ds) == 3
    np.testing.assert_array_equal(ds.times, [0.0, 0.1, 0.2])
    sizes = set()
    cfg = PRCConfig.preset("multibeam")
    for i, scan in enumerate(ds):
        row, col = truths[i]
        assert scan.name == f"{i:06d}" and scan.n_points == len(row)
        sizes.add(scan.n_points)
        assert scan.meta["organize"]["method"] == "ring-field"
        assert slot_accuracy(scan, row, col) >= 0.99
        t = scan.point_times()
        assert t is not None and i * 0.1 <= t.min() and t.max() < i * 0.1 + 0.1  # ns offsets + times.txt
        assert scan.per_point(classify_scan(scan, cfg)).shape == (len(row),)
    assert len(sizes) == 3


def test_folder_without_ring_field_and_bins(tmp_path):
    """KITTI-layout bins (x y z intensity, no ring, ring-major order) and PLY sweeps in one folder."""
    for i in range(2):
        fields, row, col = room_sweep(seed=i, layout="ring")
        pts = np.column_stack([fields["x"], fields["y"], fields["z"], fields["intensity"] / 255.0])
        pts.astype(np.float32).tofile(tmp_path / f"{i:06d}.bin")
    fields, row2, col2 = room_sweep(seed=5, layout="firing")
    write_ply(tmp_path / "000002.ply", np.column_stack([fields["x"], fields["y"], fields["z"]]))
    ds = open_dataset(tmp_path)
    assert [s.name for s in ds] == ["000000", "000001", "000002"]
    for i in range(2):
        _, row, col = room_sweep(seed=i, layout="ring")
        scan = ds[i]
        assert scan.meta["organize"]["rings"] == 16
        assert slot_accuracy(scan, row, col) >= 0.98
    scan = ds[2]
    assert scan.meta["organize"]["rings"] == 16 and slot_accuracy(scan, row2, col2) >= 0.98


def test_organised_pcd_keeps_its_grid(tmp_path):
    fields, row, col = room_sweep(dropout=0.0, layout="ring")  # 16 x 900, row-major = laser-major
    # an organised cloud as the Ouster driver writes it: H = beams, top beam first
    order = np.lexsort((col, row))
    grid = {k: v[order] for k, v in fields.items()}
    write_pcd(tmp_path / "000000.pcd", grid, height=16)
    scan = open_dataset(tmp_path / "000000.pcd")[0]
    assert scan.shape == (16, 900)
    assert scan.n_points == 16 * 900
    np.testing.assert_array_equal(scan.point_slot, np.arange(16 * 900))


def test_filtered_pcd_round_trip(tmp_path):
    """The filter command's PCD output: the input fields plus a label, read back unchanged."""
    fields, _, _ = room_sweep()
    f = write_pcd(tmp_path / "in" / "000000.pcd", fields)
    ds = SweepFolder(tmp_path / "in")
    labels = ds[0].per_point(classify_scan(ds[0], PRCConfig.preset("multibeam")))
    out = write_pcd(tmp_path / "out" / f.name, {**ds.fields(0), "label": labels.astype(np.uint8)})
    back, _ = read_pcd(out)
    assert list(back) == [*fields, "label"]
    for k, v in fields.items():
        np.testing.assert_array_equal(back[k], v)
    np.testing.assert_array_equal(back["label"], labels)
    again = SweepFolder(tmp_path / "out")[0]  # a label field does not disturb reading
    np.testing.assert_array_equal(again.point_slot, ds[0].point_slot)


def test_single_las_and_laz_sweep(tmp_path):
    fields, row, col = room_sweep(layout="firing")
    xyz = np.column_stack([fields["x"], fields["y"], fields["z"]]).astype(np.float64)
    for suffix in (".las", ".laz"):
        f = tmp_path / f"sweep{suffix}"
        write_las(f, xyz, np.ones(len(xyz), np.uint8), gps_time=1000.0 + fields["t"] * 1e-9)
        ds = open_dataset(f)
        assert ds.format == "pcd" and len(ds) == 1
        scan = ds[0]
        assert scan.n_points == len(xyz)
        assert slot_accuracy(scan, row, col) >= 0.98
        assert scan.point_times().min() >= 1000.0


def test_folder_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="unknown input format"):
        open_dataset(tmp_path / "empty")
    with pytest.raises(DataError, match=r"no \.pcd, \.ply or \.bin sweeps"):
        SweepFolder(tmp_path / "empty")
    d = tmp_path / "d"
    fields, _, _ = room_sweep()
    for i in range(2):
        write_pcd(d / f"{i}.pcd", fields)
    (d / "times.txt").write_text("0.0\n")
    with pytest.raises(DataError, match="1 times for 2 sweeps"):
        open_dataset(d)
    (tmp_path / "x.bin").write_bytes(b"\x00" * 10)
    with pytest.raises(DataError, match="truncated") as exc:
        SweepFolder(tmp_path / "x.bin")[0]
    one_line(exc, tmp_path / "x.bin")


def test_mixed_suffixes_warn(tmp_path, caplog):
    fields, _, _ = room_sweep()
    write_pcd(tmp_path / "0.pcd", fields)
    write_ply(tmp_path / "1.ply", np.column_stack([fields["x"], fields["y"], fields["z"]]))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        ds = SweepFolder(tmp_path)
    assert len(ds) == 2 and any("mixes" in r.message for r in caplog.records)


# ----------------------------------------------------------------------------- real sweeps


def test_real_vlp16_pcd_uses_channel_and_time_fields():
    f = MULTISENSOR / "velodyne_vlp16.pcd"
    if not f.is_file():
        pytest.skip(f"real sweeps not found in {MULTISENSOR}")
    fields, _ = read_pcd(f)
    scan = open_dataset(f)[0]
    assert scan.n_points == len(fields["x"]) == 14831
    assert scan.meta["organize"]["method"] == "ring-field"
    t = scan.point_times()
    # time_stamp: uint32 ns offsets (this decoder test sweep spans 1.3 ms of them)
    span = float(fields["time_stamp"].max()) - float(fields["time_stamp"].min())
    assert t is not None and np.ptp(t) == pytest.approx(span * 1e-9)
    labels = scan.per_point(classify_scan(scan, PRCConfig.preset("multibeam")))
    assert labels.shape == (14831,)


def test_map_cloud_chunks_read_pcd(tmp_path):
    """mapclass reads .pcd maps through the same reader (binary_compressed included)."""
    from data_tools.formats.clouds import cloud_chunks, cloud_size

    fields = all_types_fields(1000, seed=4)
    f = write_compressed_pcd(tmp_path / "map.pcd", fields)
    chunks = list(cloud_chunks(f, chunk=300))
    assert [len(c) for c in chunks] == [300, 300, 300, 100] and cloud_size(f) == 1000
    np.testing.assert_array_equal(np.concatenate(chunks), np.column_stack([fields["x"], fields["y"], fields["z"]]))
    bad = tmp_path / "bad.pcd"
    bad.write_text(ASCII_PCD.replace("TYPE F F F U U F", "TYPE F F F Q U F"))
    with pytest.raises(DataError, match="unknown PCD type 'Q'") as exc:
        list(cloud_chunks(bad))
    one_line(exc, bad)
