"""Map cloud files: clouds without spread or without coordinates, PLY clouds read exactly (cut ones
are errors) and LAS records beyond the header's count.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.inputs.las import ground_and_wall, write_las

laspy = pytest.importorskip("laspy")


@pytest.mark.parametrize(
    ("name", "xyz", "needle"),
    [
        ("nan.npy", np.full((50, 3), np.nan), "no point has finite coordinates"),
        ("same.npy", np.tile([3.0, 4.0, 1.0], (80, 1)), "all 80 points lie at one position (3, 4, 1)"),
        ("same.las", np.tile([3.0, 4.0, 1.0], (80, 1)), "all 80 points lie at one position (3, 4, 1)"),
        ("one.las", np.array([[3.0, 4.0, 1.0]]), "a single point (3, 4, 1)"),
    ],
)
def test_a_cloud_without_spread_is_a_one_line_error(tmp_path, name, xyz, needle):
    """A cloud without spread (80 copies of one point, or only NaNs) is a one-line error rather than a
    classification of one point or an output that LAS cannot store."""
    from data_tools.errors import DataError
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    path = tmp_path / name
    write_las(path, xyz) if name.endswith(".las") else np.save(path, xyz)
    with pytest.raises(DataError) as err:
        mapclass_job(path, Config(), tmp_path / "out")
    assert needle in str(err.value) and name in str(err.value)


def test_points_without_coordinates_are_counted_as_not_written(tmp_path):
    """An organised cloud's NaN slots get no_return and cannot be stored in LAS: the metrics (and
    the CLI) say how many points the LAS files lack."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, _ = ground_and_wall(1500)
    holes = np.arange(len(xyz)) % 4 == 0
    xyz[holes] = np.nan
    np.save(tmp_path / "holes.npy", xyz)
    metrics = mapclass_job(tmp_path / "holes.npy", Config(), tmp_path / "out")
    assert metrics["points"] == len(xyz) and metrics["counts"]["no_return"] == int(holes.sum())
    assert metrics["points_not_written"] == int(holes.sum())
    out = laspy.read(metrics["files"]["all"])
    assert len(out) == int((~holes).sum())
    np.testing.assert_allclose(np.column_stack([out.x, out.y, out.z]), xyz[~holes], atol=5e-4)


def _ply(path: Path, xyz: np.ndarray, fmt: str, *, extra: bool = True, faces: bool = True) -> Path:
    """A PLY of float32 x, y, z (with normals, an RGBA colour and two triangles when asked)."""
    order = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "<"}[fmt]
    props = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if extra:
        props += [("nx", "f4"), ("ny", "f4"), ("nz", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.zeros(len(xyz), [(k, order + t) for k, t in props])
    rec["x"], rec["y"], rec["z"] = xyz.T
    if extra:
        rec["nz"], rec["red"] = 1.0, 200
    names = {"f4": "float", "u1": "uchar"}
    head = f"ply\nformat {fmt} 1.0\ncomment h31\nelement vertex {len(xyz)}\n"
    head += "".join(f"property {names[t]} {k}\n" for k, t in props)
    head += "element face 2\nproperty list uchar int vertex_indices\n" if faces else ""
    head += "end_header\n"
    with path.open("wb") as f:
        f.write(head.encode())
        if fmt == "ascii":
            f.write("".join(" ".join(repr(v.item()) for v in r) + "\n" for r in rec).encode())
            f.write(b"3 0 1 2\n3 1 2 3\n" if faces else b"")
        else:
            f.write(rec.tobytes())
            if faces:
                tri = np.zeros(2, [("n", "u1"), ("i", order + "i4", (3,))])
                tri["n"], tri["i"] = 3, [[0, 1, 2], [1, 2, 3]]
                f.write(tri.tobytes())
    return path


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_map_clouds_are_read_exactly_and_cut_ones_are_errors(tmp_path, fmt):
    """PLY map clouds (ascii, binary little and big endian, with extra properties and faces) are read exactly; a
    PLY cut short or without y and z is a one-line error, not zeros filling the missing vertices."""
    from data_tools.errors import DataError
    from data_tools.formats.clouds import cloud_chunks

    xyz, _ = ground_and_wall(400)
    xyz = xyz.astype(np.float32).astype(np.float64)
    path = _ply(tmp_path / "map.ply", xyz, fmt)
    np.testing.assert_array_equal(np.concatenate(list(cloud_chunks(path))), xyz)
    raw = path.read_bytes()
    (tmp_path / "cut.ply").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DataError, match="truncated"):
        list(cloud_chunks(tmp_path / "cut.ply"))
    (tmp_path / "x.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n" + bytes(40)
    )
    with pytest.raises(DataError, match="have no y, z"):
        list(cloud_chunks(tmp_path / "x.ply"))


def _patch_count(path: Path, count: int) -> Path:
    """Overwrite a LAS 1.4 header's point counts (legacy, at byte 107, and 64-bit, at 247)."""
    import struct

    raw = bytearray(path.read_bytes())
    struct.pack_into("<I", raw, 107, count)
    struct.pack_into("<Q", raw, 247, count)
    path.write_bytes(bytes(raw))
    return path


def test_las_records_beyond_the_header_count_are_an_error(tmp_path):
    """A LAS header that announces fewer records than the file holds, or a file cut inside its records, is a
    one-line error rather than a silently shortened cloud."""
    from data_tools.errors import DataError
    from data_tools.formats.clouds import cloud_chunks, cloud_classes, cloud_size
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = ground_and_wall(2400)
    full = write_las(tmp_path / "full.las", xyz, classes)
    assert cloud_size(full) == len(xyz)  # a correct file passes the check
    short = tmp_path / "short.las"
    short.write_bytes(full.read_bytes())
    _patch_count(short, 1000)
    for call in (cloud_size, lambda p: list(cloud_chunks(p)), cloud_classes):
        with pytest.raises(DataError, match=f"header announces 1000 points, the file holds {len(xyz) - 1000} more"):
            call(short)
    cut = write_las(tmp_path / "cut.las", xyz, classes)
    cut.write_bytes(cut.read_bytes()[:-4500])
    with pytest.raises(DataError, match=r"header announces 3200 points, file holds \d+ \(truncated\?\)"):
        mapclass_job(cut, Config(), tmp_path / "out")
