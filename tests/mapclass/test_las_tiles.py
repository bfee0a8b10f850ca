"""LAS/LAZ tiles: the classified clouds keep the input's scale and offsets, withheld points are written
but not scored, ASPRS road surface and ignored ground count as ground.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.inputs.las import ground_and_wall, write_las

laspy = pytest.importorskip("laspy")


@pytest.mark.parametrize("scale", [0.0001, 0.01])
def test_the_classified_clouds_keep_the_input_scale_and_offsets(tmp_path, scale):
    """The classified clouds are written on the input's own grid (scale and offsets): a 0.1 mm UTM tile and a 1
    cm tile on another grid come out with every point where it was."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = ground_and_wall()
    offset = np.array([500_000.0, 5_400_000.0, 100.0])
    xyz = xyz + np.array([500_123.4567, 5_400_321.1234, 120.0])
    src = laspy.read(write_las(tmp_path / "tile.las", xyz, classes, scale=scale, offset=offset))
    metrics = mapclass_job(tmp_path / "tile.las", Config(), tmp_path / "out")
    out = laspy.read(metrics["files"]["all"])
    assert np.allclose(out.header.scales, scale) and np.allclose(out.header.offsets, offset)
    assert np.array_equal(np.asarray(out.X), np.asarray(src.X))  # the stored integers, point for point
    assert np.array_equal(np.asarray(out.Y), np.asarray(src.Y)) and np.array_equal(np.asarray(out.Z), np.asarray(src.Z))
    parts = [laspy.read(p) for k, p in metrics["files"].items() if k != "all"]
    assert sum(len(p) for p in parts) == len(src)
    for part in parts:
        assert np.allclose(part.header.scales, scale)


def test_withheld_points_are_written_but_not_scored(tmp_path):
    """Points the LAS 1.4 withheld flag marks (to be treated as deleted) are classified and written (one label
    per point) and left out of the scores (``scored_points`` counts the others)."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = ground_and_wall()
    withheld = np.arange(len(xyz)) % 5 == 0
    wrong = classes.copy()
    wrong[withheld] = 6  # withheld ground points carry a wrong class: they must not count
    write_las(tmp_path / "tile.las", xyz, wrong, withheld=withheld)
    write_las(tmp_path / "clean.las", xyz[~withheld], classes[~withheld])
    metrics = mapclass_job(tmp_path / "tile.las", Config(), tmp_path / "out")
    assert metrics["points"] == len(xyz) and len(laspy.read(metrics["files"]["all"])) == len(xyz)
    assert metrics["scored_points"] == int((~withheld).sum())
    support = {k: v["support"] for k, v in metrics["per_class"].items()}
    assert support["ground"] == int(((classes == 2) & ~withheld).sum())
    assert support["building"] == int(((classes == 6) & ~withheld).sum())
    plain = mapclass_job(tmp_path / "tile.las", Config(), tmp_path / "plain", reference=True)
    assert plain["scored_points"] == metrics["scored_points"]


def test_asprs_road_surface_and_ignored_ground_are_scored_as_ground(tmp_path):
    """ASPRS 11 (road surface) and 20 (ignored ground) in a tile's own classes are reference ground, so the
    tile's ground recall is defined and its ground points are not false positives."""
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job

    xyz, classes = ground_and_wall()
    coded = classes.copy()
    ground = np.flatnonzero(classes == 2)
    coded[ground[::2]] = 11
    coded[ground[1::2]] = 20
    write_las(tmp_path / "asprs.las", xyz, coded)
    write_las(tmp_path / "plain.las", xyz, classes)
    a = mapclass_job(tmp_path / "asprs.las", Config(), tmp_path / "a")
    b = mapclass_job(tmp_path / "plain.las", Config(), tmp_path / "b")
    assert a["per_class"] == b["per_class"]
    assert a["per_class"]["ground"]["support"] == len(ground)
