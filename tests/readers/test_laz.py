"""LAS/LAZ clouds in and out: LAZ through the lazrs backend, chosen by the file suffix."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data_tools import DataError
from data_tools.formats.clouds import cloud_chunks, cloud_size, laz_backend
from data_tools.formats.writers import ClassSplitWriter, write_las


def cloud(n: int = 5000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform([-80, -80, -3], [80, 80, 20], (n, 3))
    codes = rng.choice(np.array([1, 2, 5, 6, 7, 65], np.uint8), n)
    return xyz, codes


def is_compressed(path) -> bool:
    """LAZ sets bit 7 of the point data format id (byte 104 of the header)."""
    return bool(path.read_bytes()[104] & 0x80)


def test_laz_round_trip(tmp_path):
    xyz, codes = cloud()
    t = np.linspace(0.0, 1.0, len(xyz))
    write_las(tmp_path / "a.laz", xyz, codes, gps_time=t, point_source_id=np.arange(len(xyz)) % 7)
    write_las(tmp_path / "a.las", xyz, codes, gps_time=t)
    assert is_compressed(tmp_path / "a.laz") and not is_compressed(tmp_path / "a.las")
    assert (tmp_path / "a.laz").stat().st_size < 0.6 * (tmp_path / "a.las").stat().st_size
    las = laspy.read(tmp_path / "a.laz", laz_backend=laz_backend(tmp_path / "a.laz"))
    back = np.column_stack([las.x, las.y, las.z])
    assert np.abs(back - xyz).max() <= 0.0005 + 1e-9  # the 1 mm scale, rounded
    np.testing.assert_array_equal(np.asarray(las.classification), codes)
    np.testing.assert_array_equal(np.asarray(las.gps_time), t)
    np.testing.assert_array_equal(np.asarray(las.point_source_id), np.arange(len(xyz)) % 7)
    # streamed in chunks: same points, same order, as the uncompressed file
    assert cloud_size(tmp_path / "a.laz") == len(xyz)
    chunks = list(cloud_chunks(tmp_path / "a.laz", chunk=1234))
    assert [len(c) for c in chunks] == [1234] * 4 + [len(xyz) - 4 * 1234]
    np.testing.assert_array_equal(np.concatenate(chunks), np.concatenate(list(cloud_chunks(tmp_path / "a.las"))))


@settings(max_examples=15, deadline=None)
@given(n=st.integers(1, 300), seed=st.integers(0, 10_000))
def test_laz_round_trip_property(tmp_path_factory, n, seed):
    xyz, codes = cloud(n, seed)
    path = tmp_path_factory.mktemp("laz") / "p.laz"
    write_las(path, xyz, codes)
    back = np.concatenate(list(cloud_chunks(path)))
    assert back.shape == xyz.shape and np.abs(back - xyz).max() <= 0.0005 + 1e-9
    las = laspy.read(path)
    np.testing.assert_array_equal(np.asarray(las.classification), codes)


def test_class_split_writer_laz(tmp_path):
    xyz, codes = cloud()
    with ClassSplitWriter(tmp_path / "out", combined="map.laz") as w:
        w.write(xyz[:2000], codes[:2000])
        w.write(xyz[2000:], codes[2000:])
    paths = w.paths
    assert paths["all"].name == "map.laz"
    assert all(p.suffix == ".laz" and is_compressed(p) for p in paths.values())
    assert w.counts["all"] == len(xyz)
    assert sum(v for k, v in w.counts.items() if k != "all") == len(xyz)
    ground = laspy.read(paths["ground"])
    assert len(ground.points) == int((codes == 2).sum()) and (np.asarray(ground.classification) == 2).all()


def test_laz_without_backend_is_a_clear_error(tmp_path, monkeypatch):
    xyz, codes = cloud(10)
    write_las(tmp_path / "a.laz", xyz, codes)
    monkeypatch.setattr(laspy.LazBackend, "detect_available", staticmethod(lambda: ()))
    with pytest.raises(DataError, match=r"a\.laz: LAZ needs .*lazrs"):
        cloud_size(tmp_path / "a.laz")
    with pytest.raises(DataError, match="lazrs"):
        write_las(tmp_path / "b.laz", xyz, codes)
    assert laz_backend(tmp_path / "a.las") is None  # plain LAS needs no backend


def test_truncated_laz_is_a_clear_error(tmp_path):
    xyz, codes = cloud()
    write_las(tmp_path / "a.laz", xyz, codes)
    data = (tmp_path / "a.laz").read_bytes()
    (tmp_path / "cut.laz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match=r"cut\.laz"):
        list(cloud_chunks(tmp_path / "cut.laz"))
