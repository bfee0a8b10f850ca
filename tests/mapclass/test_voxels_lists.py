"""Neighbour lists of large voxel grids walked in two halves side by side
(prc_slam.util.voxels._merge_neighbours): the same lists as one walk and as the 27 hash probes."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import prc_slam.util.voxels as V
from prc_slam.util.voxels import VoxelGrid, _hash_neighbours, _merge_neighbours


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 2000), spread=st.sampled_from([1.0, 5.0, 50.0]), seed=st.integers(0, 2**31 - 1))
def test_halves_equal_the_hash_probes(n, spread, seed):
    rng = np.random.default_rng(seed)
    g = VoxelGrid.build(rng.uniform(-spread, spread, size=(n, 3)), 0.5)
    hs, hn = _hash_neighbours(g.table, g.coords)
    keep, V.SPLIT_MIN_VOXELS = V.SPLIT_MIN_VOXELS, 2  # split at any size here
    try:
        ms, mn = _merge_neighbours(g.coords)
    finally:
        V.SPLIT_MIN_VOXELS = keep
    np.testing.assert_array_equal(ms, hs)
    np.testing.assert_array_equal(mn, hn)


def test_large_grid_split_walk_is_the_single_walk(monkeypatch):
    # a rough surface of ~300 k voxels: above the split size, lists from both halves
    rng = np.random.default_rng(5)
    x, y = rng.uniform(0, 300, (2, 600_000))
    pts = np.column_stack([x, y, np.sin(x / 7) + 0.3 * rng.random(len(x))])
    g = VoxelGrid.build(pts, 0.5)
    assert g.n_voxels >= V.SPLIT_MIN_VOXELS
    split = _merge_neighbours(g.coords)
    monkeypatch.setattr(V, "SPLIT_MIN_VOXELS", 10**12)
    single = _merge_neighbours(g.coords)
    for a, b in zip(split, single, strict=True):
        np.testing.assert_array_equal(a, b)
    hs, hn = _hash_neighbours(g.table, g.coords)
    np.testing.assert_array_equal(split[0], hs)
    np.testing.assert_array_equal(split[1], hn)
