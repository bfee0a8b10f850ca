"""Geo-referenced map clouds (UTM-like coordinates): LAS with a 1 mm scale keeps every coordinate and
gives the labels of the same cloud at the origin; float32 coordinates that large are warned; the
classified clouds keep the input's coordinate reference system.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from data_tools.formats.pcd import write_pcd
from tests.inputs.clouds import UTM, block_building


def write_las(path: Path, xyz: np.ndarray, scale: float = 0.001) -> Path:
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(path)
    return path


def test_utm_las_with_a_millimetre_scale_keeps_its_geometry_and_labels(tmp_path):
    """The same cloud at the origin and at UTM coordinates: the written coordinates are the
    input's to the millimetre, and the labels agree (up to the voxel grids' other alignment)."""
    import laspy

    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz = np.round(block_building(), 3)
    results = {}
    for name, shift in (("origin", np.zeros(3)), ("utm", UTM)):
        path = write_las(tmp_path / f"{name}.las", xyz + shift)
        metrics = mapclass_job(path, Config(), tmp_path / name)
        out = laspy.read(metrics["files"]["all"])
        written = np.column_stack([out.x, out.y, out.z]) - shift
        assert len(written) == len(xyz)
        np.testing.assert_allclose(written, xyz, atol=1.5e-3)
        results[name] = np.asarray(out.classification)
        assert (results[name] == 6).mean() > 0.3 and (results[name] == 2).mean() > 0.3  # building and ground
    assert np.mean(results["origin"] == results["utm"]) > 0.98


def _ply_float32(path: Path, xyz: np.ndarray) -> Path:
    from data_tools.formats.writers import write_ply

    write_ply(path, xyz)
    return path


def _npy(path: Path, xyz: np.ndarray) -> Path:
    np.save(path, xyz)
    return path


def _pcd(path: Path, xyz: np.ndarray) -> Path:
    write_pcd(path, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
    return path


@pytest.mark.parametrize(
    ("suffix", "writer"), [(".pcd", _pcd), (".npy", _npy), (".ply", _ply_float32)], ids=["pcd", "npy", "ply"]
)
def test_float32_utm_coordinates_are_warned(tmp_path, caplog, suffix, writer):
    """float32 northings of 5.4e6 keep one value per 0.5 m: the reader warns before the cloud is classified."""
    from data_tools.formats.clouds import cloud_chunks

    xyz = block_building(3000) + UTM
    path = writer(tmp_path / f"utm32{suffix}", xyz.astype(np.float32))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        got = np.concatenate(list(cloud_chunks(path)))
        list(cloud_chunks(path))
    assert len(got) == len(xyz)
    warned = [r.getMessage() for r in caplog.records if "stored with a step" in r.getMessage()]
    assert len(warned) == 1 and "float32" in warned[0] and "step of 0.5" in warned[0] and path.name in warned[0]


@pytest.mark.parametrize("case", ["float64 at UTM", "float32 at the origin"])
def test_fine_enough_coordinates_are_not_warned(tmp_path, caplog, case):
    from data_tools.formats.clouds import cloud_chunks

    xyz = block_building(3000)
    if case == "float64 at UTM":
        xyz = xyz + UTM
    else:
        xyz = xyz.astype(np.float32)
    paths = [_pcd(tmp_path / "c.pcd", xyz), _npy(tmp_path / "c.npy", xyz)]
    if case == "float32 at the origin":
        paths.append(_ply_float32(tmp_path / "c.ply", xyz))
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        for path in paths:
            got = np.concatenate(list(cloud_chunks(path)))
            np.testing.assert_allclose(got, np.asarray(xyz, np.float64), atol=1e-9)
    assert not [r for r in caplog.records if "stored with a step" in r.getMessage()]


UTM32N_WKT = (
    'PROJCS["WGS 84 / UTM zone 32N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
    'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
    'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",9],PARAMETER["scale_factor",0.9996],'
    'PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1],AUTHORITY["EPSG","32632"]]'
)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_the_classified_clouds_keep_the_input_crs(tmp_path, suffix):
    """The classified clouds of a UTM tile carry its WKT coordinate reference system, so a GIS places them where
    the input was."""
    import laspy
    from laspy.vlrs.known import WktCoordinateSystemVlr

    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz = np.round(block_building(6000), 3) + UTM
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.floor(xyz.min(axis=0))
    header.vlrs.append(WktCoordinateSystemVlr(UTM32N_WKT))
    header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(tmp_path / f"tile{suffix}")
    plain = write_las(tmp_path / "plain.las", xyz)
    metrics = mapclass_job(tmp_path / f"tile{suffix}", Config(), tmp_path / "out", laz=suffix == ".laz")
    assert len(metrics["files"]) > 2
    for path in metrics["files"].values():
        out = laspy.read(path)
        wkt = [v for v in out.header.vlrs if isinstance(v, WktCoordinateSystemVlr)]
        assert len(wkt) == 1 and "UTM zone 32N" in wkt[0].string and out.header.global_encoding.wkt
    metrics = mapclass_job(plain, Config(), tmp_path / "plain")
    assert not laspy.read(metrics["files"]["all"]).header.vlrs
