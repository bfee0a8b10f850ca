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
    base = FilterConfig(cell=1.0, sample={}, sample_other=0.5, source_cell={"ground": 10.0}, representative="first")
    return base.model_copy(update=update)


# four ground points in the 1 m cell (0, 0): sampled at 0.5 m, dense; one each in (3, 0) and (5, 0)
PTS = np.array([[0.1, 0.1, 0], [0.6, 0.1, 0], [0.1, 0.6, 0], [0.6, 0.6, 0], [3.2, 0.5, 0], [5.5, 0.5, 0]], float)
LAB = np.full(6, G, np.uint8)


def test_densely_sampled_ground_is_registered_in_full_and_sparse_ground_on_the_coarse_grid():
    res = filter_points(PTS, LAB, _config())
    assert res.keep.tolist() == [True, False, False, False, True, True]  # the map: one point per 1 m cell
    # cell (0, 0) held 4 >= (1 / 0.5)^2 points: its point is registered; the two sparse cells
    # share one 10 m source cell: its first point stands for both
    assert res.source.tolist() == [True, False, False, False, True, False]
    # the policy before: the 10 m grid everywhere (the dense point takes the one source cell)
    before = filter_points(PTS, LAB, _config(source_dense=[]))
    assert before.source.tolist() == [True, False, False, False, False, False]
    # a spacing of 1 m calls every occupied 1 m cell dense: every kept point is registered
    assert np.array_equal(filter_points(PTS, LAB, _config(dense_spacing=1.0)).source, res.keep)
    # a finer spacing than the scan's (0.25 m: 16 points a cell) calls no cell dense
    assert np.array_equal(filter_points(PTS, LAB, _config(dense_spacing=0.25)).source, before.source)


def test_dense_rule_applies_to_sampled_classes_and_never_to_excluded_ones():
    # building on 0.5 m cubes: eight points in the cube at the origin, one in the next
    cube = np.array([[x, y, z] for x in (0.1, 0.3) for y in (0.1, 0.3) for z in (0.1, 0.3)] + [[0.7, 0.1, 0.1]])
    lab = np.full(9, B, np.uint8)
    cfg = _config(source_cell={"building": 5.0}, source_dense=["building"], dense_spacing=0.25)
    res = filter_points(cube, lab, cfg)
    assert np.flatnonzero(res.keep).tolist() == [0, 8]
    assert np.flatnonzero(res.source).tolist() == [0, 8]  # 8 >= (0.5 / 0.25)^2: in full; 8 on the 5 m grid
    excluded = filter_points(PTS, LAB, _config(source_exclude=["ground"]))
    assert not excluded.source.any()  # excluded from registration even where dense


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
def test_dense_rule_only_adds_ground_and_adds_every_dense_cell(seed, n, spacing, representative):
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(-4, 4, (n, 2)), rng.uniform(0, 2, n)]
    lab = rng.choice(np.array([G, B, L.VEGETATION, L.NOISE], np.uint8), n)
    cfg = FilterConfig(
        source_cell={"ground": 5.0, "building": 4.0, "vegetation": 3.0},
        dense_spacing=spacing,
        representative=representative,
    )
    new = filter_points(pts, lab, cfg)
    old = filter_points(pts, lab, cfg.model_copy(update={"source_dense": []}))
    assert np.array_equal(new.keep, old.keep)  # the map is untouched
    assert not (new.source & ~new.keep).any()
    assert not (old.source & ~new.source).any()  # only adds points
    assert np.array_equal(new.source[lab != G], old.source[lab != G])  # and only ground
    # every kept ground point standing for a 1 m cell with >= (1 / spacing)^2 ground points is registered
    cells = np.floor(pts[:, :2] / cfg.cell).astype(np.int64)
    ground = lab == G
    _, inverse, counts = np.unique(cells[ground], axis=0, return_inverse=True, return_counts=True)
    dense = np.zeros(n, bool)
    dense[np.flatnonzero(ground)] = counts[inverse.ravel()] >= round((cfg.cell / spacing) ** 2)
    assert new.source[dense & new.keep].all()
