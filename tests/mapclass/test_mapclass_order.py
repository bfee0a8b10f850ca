"""The spatial order of the map classification (prc_slam.mapclass.order): a permutation, a
function of the set of points alone, and labels that no longer depend on the input order."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam import labels as L
from prc_slam.mapclass import MapClassConfig, classify_map
from prc_slam.mapclass.classify import DensityWarning
from prc_slam.mapclass.order import _morton_keys, _spread3, is_local, spatial_order


def test_morton_spread_hand_computed():
    # bit i goes to bit 3i
    assert int(_spread3(np.uint64(0b1))) == 0b1
    assert int(_spread3(np.uint64(0b101))) == 0b1000001
    assert int(_spread3(np.uint64(0b11))) == 0b1001
    assert int(_spread3(np.uint64(0xFFFF))) == sum(1 << (3 * i) for i in range(16))


def test_hand_computed_order():
    # bounding box 0..1 on every axis: cubes of 1/65535 m, so every point its own cube; the
    # Morton key puts (0,0,0) first, then x-neighbours before y before z at the same level
    pts = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert spatial_order(pts).tolist() == [4, 3, 2, 1, 0]
    # one cube (all points within 1e-9 of each other in a 1 km box): x, then y, then z
    pts = np.array([[5e-10, 0.0, 0.0], [0.0, 1e-10, 0.0], [0.0, 0.0, 1e-10], [0.0, 0.0, 0.0], [1000.0, 0, 0]])
    assert spatial_order(pts).tolist() == [3, 2, 1, 0, 4]


def test_bad_input():
    assert spatial_order(np.zeros((0, 3))).tolist() == []
    assert spatial_order(np.ones((3, 3))).tolist() == [0, 1, 2]  # equal rows keep their order
    with pytest.raises(ValueError, match="finite"):
        spatial_order(np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(0, 3000),
    spread=st.floats(1e-6, 1e4),
    duplicates=st.integers(0, 50),
    crowd=st.integers(0, 200),
    seed=st.integers(0, 2**16),
)
def test_a_permutation_and_the_same_sorted_cloud_for_any_input_order(n, spread, duplicates, crowd, seed):
    rng = np.random.default_rng(seed)
    pts = rng.normal(0, spread, (n, 3))
    if n:  # repeated rows, and many points in one cube (the long runs' heap sort)
        pts = np.concatenate([pts, pts[rng.integers(0, n, duplicates)], pts[0] + rng.normal(0, 1e-12, (crowd, 3))])
    order = spatial_order(pts)
    assert np.array_equal(np.sort(order), np.arange(len(pts)))
    shuffled = pts[rng.permutation(len(pts))]
    np.testing.assert_array_equal(shuffled[spatial_order(shuffled)], pts[order])
    # Morton keys ascending; within a cube (equal keys), x, then y, then z ascending
    keys = np.empty(len(pts), np.uint64)
    assert _morton_keys(pts, keys)
    k, s = keys[order], pts[order]
    assert (k[1:] >= k[:-1]).all()
    same = np.flatnonzero(k[1:] == k[:-1])
    rows = [tuple(s[i]) <= tuple(s[i + 1]) for i in same]
    assert all(rows)


def _scene(rng):
    """A ground plane, a wall, a car-sized box and scattered outliers."""
    x, y = np.meshgrid(np.arange(-10, 10, 0.1), np.arange(-6, 6, 0.1), indexing="ij")
    ground = np.column_stack([x.ravel(), y.ravel(), rng.normal(0, 0.01, x.size)])
    u, z = np.meshgrid(np.arange(-10, 10, 0.1), np.arange(0, 6, 0.1), indexing="ij")
    wall = np.column_stack([u.ravel(), np.full(u.size, 5.5), z.ravel()])
    a, b = np.meshgrid(np.arange(-2, 2, 0.08), np.arange(-0.8, 0.8, 0.08), indexing="ij")
    roof = np.column_stack([a.ravel(), b.ravel(), np.full(a.size, 1.5)])
    noise = rng.uniform([-10, -6, 0], [10, 6, 10], (200, 3))
    return np.concatenate([ground, wall, roof, noise])


def test_shuffled_cloud_same_labels_point_for_point():
    rng = np.random.default_rng(3)
    pts = _scene(rng)
    pts[::997] = np.nan  # non-finite rows keep their place too
    perm = rng.permutation(len(pts))
    always = MapClassConfig(spatial_order="always")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DensityWarning)
        a = classify_map(pts, always)
        b = classify_map(pts[perm], always)
        unsorted = classify_map(pts, MapClassConfig(spatial_order="never"))
        auto = classify_map(pts)  # the scene is built row by row: local, not sorted
        auto_shuffled = classify_map(pts[perm])  # not local: sorted
    np.testing.assert_array_equal(b.labels, a.labels[perm])
    np.testing.assert_array_equal(b.segment, a.segment[perm])
    np.testing.assert_array_equal(b.density, a.density[perm])
    np.testing.assert_array_equal(b.verticality, a.verticality[perm])
    assert (a.labels[np.isnan(pts[:, 0])] == L.NO_RETURN).all()
    assert (a.labels == L.GROUND).sum() > 0.9 * 200 * 120
    # the same classification as in input order: the same density, the same labels on this scene
    np.testing.assert_array_equal(a.density, unsorted.density)
    np.testing.assert_array_equal(a.labels, unsorted.labels)
    assert "order" in a.seconds and "order" not in unsorted.seconds
    assert "order" not in auto.seconds and "order" in auto_shuffled.seconds
    np.testing.assert_array_equal(auto.labels, unsorted.labels)
    np.testing.assert_array_equal(auto_shuffled.labels, b.labels)


def test_is_local_hand_computed():
    line = np.column_stack([np.arange(100) * 0.5, np.zeros(100), np.zeros(100)])  # steps of 0.5 m
    assert is_local(line, 1.0) and not is_local(line, 0.5)  # shorter than the step, strictly
    jumpy = line.copy()
    jumpy[::5, 0] += 100.0  # 2 steps in 5 long (into and out of each moved point)
    assert not is_local(jumpy, 1.0) and is_local(jumpy, 1.0, share=0.6)
    assert is_local(np.zeros((1, 3)), 1.0) and is_local(np.zeros((0, 3)), 1.0)
    assert not is_local(np.array([[0.0, 0, 0], [np.nan, 0, 0]]), 1.0)  # a non-finite step is long
