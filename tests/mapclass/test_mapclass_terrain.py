"""Map classification's ground (paper 004, Sec. 4.1) on airborne terrain the flat scenes lack:
hills, a 30 deg hillside, terraces and an embankment, canopy on a slope, a quarry,
a river with a bridge, large roofs; the tiles of :mod:`data_tools.sim.terrain`.

``terrain_relative`` of :func:`detect_ground` (the opening, ground followed up unbroken slopes,
the slope-relative point tolerance) is ``GroundParams.terrain``: ``auto`` (the default) runs it on
clouds of airborne density and where the terrain is not level (:func:`terrain_relief`), ``off`` is
the paper's test. Before it (the paper's test), ground precision / recall on these tiles was:
flat 1.000 / 1.000, hills 1.000 / 0.184, slope 0.912 / 0.008, terraces 1.000 / 0.279,
forest_slope 0.997 / 0.016, cliff 1.000 / 0.739, river 0.984 / 0.495, roofs 0.964 / 0.941:
every cell was compared with the minimum of the window centred on it, which on a slope lies
``slope x radius x sqrt 2`` lower (0.5 m allowed: fails from ~7 deg), below every rim of a
terrace or a quarry, and a 0.2 m point tolerance drops most points of a cell on a 30 deg slope.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scipy.ndimage import grey_opening

from data_tools.sim.terrain import CASES, TerrainConfig, ground_scores, simulate_terrain
from prc_slam import labels as L
from prc_slam.mapclass import classify_map
from prc_slam.mapclass.classify import GroundParams, MapClassConfig, paper_config
from prc_slam.mapclass.ground import detect_ground, opening_window, terrain_relief

#: ground precision and recall floors with ``terrain_relative`` (measured: flat 0.999 / 1.000,
#: hills 1.000 / 0.966, slope 1.000 / 0.958, terraces 1.000 / 0.903, forest_slope 1.000 / 0.937,
#: cliff 1.000 / 0.939, river 0.982 / 0.992, roofs 0.953 / 0.990); each recall floor here but
#: flat's and roofs' is above the paper test's figure in the module docstring
FLOORS = {
    "flat": (0.99, 0.99),
    "hills": (0.98, 0.93),
    "slope": (0.98, 0.92),
    "terraces": (0.98, 0.87),
    "forest_slope": (0.98, 0.90),
    "cliff": (0.98, 0.90),
    "river": (0.97, 0.96),  # the bridge deck (not ground) stays ground where it meets the banks
    "roofs": (0.94, 0.97),  # the middle of a 70 x 45 m roof passes the scan lines (as before)
}


def classify_ground(points: np.ndarray, terrain: str = "auto") -> np.ndarray:
    """``classify_map``'s labels (default config, ``GroundParams.terrain`` as given)."""
    cfg = MapClassConfig(ground=GroundParams(terrain=terrain))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return classify_map(points, cfg).labels


@pytest.fixture(scope="module")
def tiles():
    return {case: simulate_terrain(TerrainConfig(case=case)) for case in CASES}


def test_terrain_tiles_truth_returns_and_determinism(tiles):
    for case, c in tiles.items():
        n = len(c)
        assert n > 10_000, case
        for a in (c.labels, c.instance, c.return_number, c.number_of_returns):
            assert len(a) == n
        assert (c.return_number >= 1).all() and (c.return_number <= c.number_of_returns).all()
        assert (np.abs(c.points[:, :2]) < 50).all()
        assert {L.GROUND, L.VEGETATION}.issubset(set(np.unique(c.labels).tolist()))
    f = tiles["forest_slope"]
    assert (f.labels == L.GROUND).mean() < 0.15 and (f.number_of_returns > 1).mean() > 0.3  # closed canopy
    assert (tiles["river"].labels == L.UNCLASSIFIED).any()  # the bridge deck
    again = simulate_terrain(TerrainConfig(case="hills"))
    np.testing.assert_array_equal(again.points, tiles["hills"].points)
    with pytest.raises(ValueError, match="unknown terrain case"):
        simulate_terrain(TerrainConfig(case="moon"))


@pytest.mark.parametrize("case", CASES)
def test_terrain_ground_precision_recall(tiles, case):
    """With the default config (``auto``: these tiles are of airborne density)."""
    c = tiles[case]
    p, r = ground_scores(classify_ground(c.points) == L.GROUND, c.labels)
    pf, rf = FLOORS[case]
    assert p >= pf and r >= rf, f"{case}: ground {p:.3f} / {r:.3f}"


def test_paper_ground_unchanged_by_default():
    """``terrain_relative`` is off unless asked for: the paper's Sec. 4.1 as before."""
    c = simulate_terrain(TerrainConfig(case="slope"))
    np.testing.assert_array_equal(detect_ground(c.points), detect_ground(c.points, terrain_relative=False))
    assert detect_ground(c.points).mean() < 0.05  # the hillside is lost by the paper's test


def test_flat_scenes_unchanged_or_better():
    """On the flat airborne-like scenes ground is as good as before (recall better on the sparse
    one: 0.948 -> 0.999; precision within 0.3 points)."""
    from tests.inputs.clouds import airborne_like

    for pts, ref in (airborne_like(2.0), airborne_like(4.0, seed=1), _flat_tile()):
        before = ground_scores(classify_ground(pts, "off") == L.GROUND, ref)
        after = ground_scores(classify_ground(pts, "on") == L.GROUND, ref)
        assert after[0] >= before[0] - 0.003 and after[1] >= before[1] - 1e-9, (before, after)


def _flat_tile():
    c = simulate_terrain(TerrainConfig(case="flat", seed=1))
    return c.points, c.labels


def test_opening_window_is_the_grey_opening_and_keeps_planes_and_rims():
    rng = np.random.default_rng(5)
    a = rng.normal(0, 1, (23, 31))
    ref = grey_opening(np.pad(a, 2, constant_values=np.inf), size=(5, 5))[2:-2, 2:-2]  # nothing past the edge
    np.testing.assert_allclose(opening_window(a, 5), ref)
    x, y = np.meshgrid(np.arange(20.0), np.arange(20.0), indexing="ij")
    slope = 0.7 * x - 0.3 * y
    np.testing.assert_allclose(opening_window(slope, 7), slope)  # any plane: itself
    step = np.where(x < 10, 0.0, 3.0)  # a terrace: the rim keeps its height
    np.testing.assert_allclose(opening_window(step, 7), step)
    box = np.zeros((20, 20))
    box[8:11, 8:11] = 2.0  # narrower than the window: the ground beside it
    assert opening_window(box, 7).max() == 0.0
    gaps = slope.copy()
    gaps[::3, ::2] = np.inf  # empty cells take no part
    o = opening_window(gaps, 5)
    np.testing.assert_allclose(o[np.isfinite(gaps)], slope[np.isfinite(gaps)])


def test_terrain_relief_hand_cases():
    """The median slope between 10 m blocks of the grid minimum: a plane's own slope, a level
    grid with one roof block nearly 0, fewer than two blocks 0."""
    x, y = np.meshgrid(np.arange(60) * 0.5, np.arange(60) * 0.5, indexing="ij")
    # 3 x 3 blocks: six pairs along x rising 0.2 per metre, six along y 0.1: the median 0.15
    assert terrain_relief(0.2 * x + 0.1 * y, 0.5) == pytest.approx(0.15)
    level = np.zeros((60, 60))
    level[:20, :20] = 8.0  # a roof over a whole block
    assert terrain_relief(level, 0.5) == 0.0
    holes = np.full((60, 60), np.inf)
    holes[:20, :20] = 1.0
    assert terrain_relief(holes, 0.5) == 0.0


def test_auto_takes_the_terrain_tests_where_the_terrain_is_not_level(tiles):
    """Dense clouds (above ``terrain_max_density``: mobile mapping, terrestrial) get the paper's
    test on level ground and the terrain tests on a hillside; airborne ones always; the paper's
    config never. A hillside made dense (x 16 points, jittered) loses its ground to the paper's test
    and keeps it with ``auto``."""
    slope = tiles["slope"]
    rng = np.random.default_rng(3)
    dense = np.concatenate([slope.points + rng.normal(0, 0.02, slope.points.shape) for _ in range(16)])
    truth = np.tile(slope.labels, 16)
    auto = classify_map(dense)
    assert auto.scale.rho > 100 and auto.choices["terrain"] and auto.choices["relief"] > 0.3
    p, r = ground_scores(auto.labels == L.GROUND, truth)
    assert p >= 0.95 and r >= 0.9, (p, r)
    paper = classify_map(dense, MapClassConfig(ground=GroundParams(terrain="off")))
    assert not paper.choices["terrain"] and ground_scores(paper.labels == L.GROUND, truth)[1] < 0.1
    flat = tiles["flat"]
    dense_flat = np.concatenate([flat.points + rng.normal(0, 0.02, flat.points.shape) for _ in range(16)])
    res = classify_map(dense_flat)
    assert res.scale.rho > 100 and not res.choices["terrain"] and res.choices["relief"] < 0.05
    airborne = classify_map(flat.points).choices
    assert airborne["terrain"] and "relief" not in airborne  # airborne density: no relief asked
    off = MapClassConfig(ground=GroundParams(terrain="off"))
    assert classify_map(flat.points, off).choices["terrain"] is False and paper_config().ground.terrain == "off"


@pytest.mark.parametrize("case", ["hills", "forest_slope", "river"])
def test_wooded_tiles_in_urban_mode_take_their_foliage_as_vegetation(tiles, case):
    """Once the ground of a wooded tile is found, the trees are most of what is left, and Sec. 4.5's
    'segment density higher than on average' has no contrast: vegetation recall was 0.22 / 0.00 /
    0.32 (0.99 / 0.01 / 0.87 while the ground was lost and counted in the average). Where foliage
    is half the points off the ground or more (``canopy_share``), foliage alone is vegetation, as in
    forest mode."""
    from prc_slam.mapclass.classify import VegetationParams

    c = tiles[case]
    truth = c.labels == L.VEGETATION

    def scores(labels: np.ndarray) -> tuple[float, float]:
        tp = float(np.count_nonzero((labels == L.VEGETATION) & truth))
        return tp / max(np.count_nonzero(labels == L.VEGETATION), 1), tp / max(np.count_nonzero(truth), 1)

    now = scores(classify_ground(c.points))
    paper_rule = scores(classify_map(c.points, MapClassConfig(vegetation=VegetationParams(canopy_share=None))).labels)
    assert now[0] >= 0.95 and now[1] >= 0.85, now
    assert paper_rule[1] < 0.4, paper_rule


def test_mapclass_says_when_the_ground_followed_the_terrain(tiles, tmp_path):
    from typer.testing import CliRunner

    from data_tools.sim.airborne import write_cloud
    from prc_slam.cli import app

    laz = write_cloud(tiles["hills"], tmp_path / "hills.laz")
    res = CliRunner().invoke(
        app, ["mapclass", str(laz), "--out", str(tmp_path / "o"), "--json", str(tmp_path / "m.json")]
    )
    assert res.exit_code == 0, res.output
    assert "ground: terrain-relative tests" in res.output and "vegetation: the foliage alone" in res.output, res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["density"]["terrain_ground_share"] == 1.0 and m["per_class"]["ground"]["recall"] >= 0.93
    assert m["density"]["canopy_share"] == 1.0  # the hills tile is wooded
