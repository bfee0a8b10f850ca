"""The registration source keeps the ground in full where the scan samples it densely
(``FilterConfig.source_dense``, ``dense_spacing``) and on the coarse ``source_cell`` grid
elsewhere."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam import labels as L
from prc_slam.filtering import FilterConfig, filter_points

G, B = L.GROUND, L.BUILDING


def _config(**update) -> FilterConfig:
    base = FilterConfig(
        cell=1.0,
        sample={},
        sample_other=0.5,
        source_cell={"ground": 10.0},
        source_dense=["ground"],
        dense_spacing=0.5,
        representative="first",
    )
    return base.model_copy(update=update)


# four ground points in the 1 m cell (0, 0): sampled at 0.5 m, dense; one each in (3, 0) and (5, 0)
PTS = np.array([[0.1, 0.1, 0], [0.6, 0.1, 0], [0.1, 0.6, 0], [0.6, 0.6, 0], [3.2, 0.5, 0], [5.5, 0.5, 0]], float)
LAB = np.full(6, G, np.uint8)


def test_densely_sampled_ground_is_registered_in_full_and_sparse_ground_on_the_coarse_grid():
    res = filter_points(PTS, LAB, _config())
    assert res.keep.tolist() == [True, False, False, False, True, True]  # the map: one point per 1 m cell
    # the four 0.5 m quarters of cell (0, 0) hold a point: its point is registered; the two sparse cells
    # share one 10 m source cell: its first point stands for both
    assert res.source.tolist() == [True, False, False, False, True, False]
    # the policy before: the 10 m grid everywhere (the dense point takes the one source cell)
    before = filter_points(PTS, LAB, _config(source_dense=[]))
    assert before.source.tolist() == [True, False, False, False, False, False]
    # a spacing of 1 m calls every occupied 1 m cell dense: every kept point is registered
    assert np.array_equal(filter_points(PTS, LAB, _config(dense_spacing=1.0)).source, res.keep)
    # a finer spacing than the scan's (0.25 m: 16 sub-cells, 4 occupied) calls no cell dense
    assert np.array_equal(filter_points(PTS, LAB, _config(dense_spacing=0.25)).source, before.source)


def test_dense_rule_applies_to_sampled_classes_and_never_to_excluded_ones():
    # building on 0.5 m cubes: eight points filling the cube at the origin, one in the next
    cube = np.array([[x, y, z] for x in (0.1, 0.3) for y in (0.1, 0.3) for z in (0.1, 0.3)] + [[0.7, 0.1, 0.1]])
    lab = np.full(9, B, np.uint8)
    cfg = _config(source_cell={"building": 5.0}, source_dense=["building"], dense_spacing=0.25)
    res = filter_points(cube, lab, cfg)
    assert np.flatnonzero(res.keep).tolist() == [0, 8]
    # 8 of its 8 0.25 m sub-cubes hold a point (>= 2^2, a surface's worth): in full; 8 on the 5 m grid
    assert np.flatnonzero(res.source).tolist() == [0, 8]
    excluded = filter_points(PTS, LAB, _config(source_exclude=["ground"]))
    assert not excluded.source.any()  # excluded from registration even where dense


def test_ring_of_close_points_is_not_dense():
    # a ring crossing the 1 m cell (0, 0): a hundred points along a line, in two of its four
    # quarters; and a lone ground point in the same 10 m source cell
    ring = np.c_[np.linspace(0.01, 0.99, 100), np.full(100, 0.2), np.zeros(100)]
    lone = np.array([[3.2, 0.5, 0.0]])
    one = filter_points(np.r_[ring, lone], np.full(101, G, np.uint8), _config())
    assert one.keep.sum() == 2 and one.source.sum() == 1  # one point for the 10 m cell
    second = ring + np.array([0.0, 0.5, 0.0])  # a second ring 0.5 m away: every quarter covered
    two = filter_points(np.r_[ring, second, lone], np.full(201, G, np.uint8), _config())
    assert two.keep.sum() == 2 and two.source.sum() == 2  # the dense cell in full, the lone point on the grid
    # a spacing finer than 1/8 of the cell is tested at 1/8 (64 sub-cells, 4 occupied): not dense
    assert (
        filter_points(np.r_[ring, second, lone], np.full(201, G, np.uint8), _config(dense_spacing=0.05)).source.sum()
        == 1
    )


def test_unknown_dense_class_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown class 'leaves' in the filter's source_dense"):
        filter_points(PTS, LAB, _config(source_dense=["leaves"]))
    with pytest.raises(ValueError):
        FilterConfig(dense_spacing=0.0)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(1, 400),
    spacing=st.sampled_from([0.25, 0.5, 1.0]),
    representative=st.sampled_from(["first", "random"]),
)
def test_dense_rule_only_adds_ground_every_dense_cell_and_the_cells_it_frees(seed, n, spacing, representative):
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(-4, 4, (n, 2)), rng.uniform(0, 2, n)]
    lab = rng.choice(np.array([G, B, L.VEGETATION, L.NOISE], np.uint8), n)
    cfg = FilterConfig(
        source_cell={"ground": 5.0, "building": 4.0, "vegetation": 3.0},
        source_dense=["ground"],
        dense_spacing=spacing,
        representative=representative,
    )
    new = filter_points(pts, lab, cfg)
    old = filter_points(pts, lab, cfg.model_copy(update={"source_dense": []}))
    assert np.array_equal(new.keep, old.keep)  # the map is untouched
    assert not (new.source & ~new.keep).any()
    assert not (old.source & ~new.source).any()  # only adds points
    assert np.array_equal(new.source[lab != G], old.source[lab != G])  # and only ground
    # every kept ground point standing for a 1 m cell whose every sub-cell of side `spacing` holds
    # a ground point is registered
    k = round(cfg.cell / spacing)
    ground = np.flatnonzero(lab == G)
    cells = np.floor(pts[ground, :2] / cfg.cell).astype(np.int64)
    subs = np.floor(pts[ground, :2] / spacing).astype(np.int64) - cells * k
    covered = {}
    for c, s in zip(map(tuple, cells), map(tuple, subs), strict=True):
        covered.setdefault(c, set()).add(s)
    dense = np.zeros(n, bool)
    dense[ground] = [len(covered[tuple(c)]) == k * k for c in cells]
    assert new.source[dense & new.keep].all()
    # and nothing else, but for a sparse point taking over a coarse source cell whose point stood
    # for it before and is now registered as dense ground: at most one per such cell
    source_cell = cfg.source_cell["ground"]
    coarse = np.floor(pts[:, :2] / source_cell).astype(np.int64)
    freed = {tuple(c) for c in coarse[old.source & dense]}
    taken = [tuple(c) for c in coarse[new.source & ~old.source & ~dense]]
    assert set(taken) <= freed
    assert len(taken) == len(set(taken))


def test_the_dense_rule_is_off_by_default():
    """The default registers the coarse grids everywhere (the rule bought accuracy with time at the
    same rate as more registered points: docs/RESULTS.md)."""
    assert FilterConfig().source_dense == []
