"""Map classification after registration (paper 004): each step on constructed clouds, bad
input, tiling, segregation files, and the whole pipeline on a simulated urban map."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam import labels as L
from prc_slam.mapclass import MapClassConfig, classify_map, to_world
from prc_slam.mapclass import metrics as M
from prc_slam.mapclass.classify import DensityWarning
from prc_slam.mapclass.ground import detect_ground
from prc_slam.mapclass.objects import (
    compact,
    detect_buildings,
    detect_posts,
    detect_vegetation,
    detect_vehicles,
    height_above_ground,
    segment_voxels,
)
from prc_slam.mapclass.tiles import array_chunks, classify_tiled
from prc_slam.util.voxels import VoxelGrid

RNG = np.random.default_rng(0)


# ---- constructed clouds --------------------------------------------------------------------


def plane(x0, x1, y0, y1, z=0.0, step=0.05, slope=0.0):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step), indexing="ij")
    x, y = x.ravel(), y.ravel()
    return np.column_stack([x, y, z + slope * x + RNG.normal(0, 0.003, len(x))])


def wall(x0, x1, y, z0, z1, step=0.05):
    x, z = np.meshgrid(np.arange(x0, x1, step), np.arange(z0, z1, step), indexing="ij")
    return np.column_stack([x.ravel(), np.full(x.size, y) + RNG.normal(0, 0.003, x.size), z.ravel()])


def box(cx, cy, lx, ly, z0, z1, step=0.05):
    """The five visible faces (no bottom) of an axis-aligned box."""
    faces = [
        wall(cx - lx / 2, cx + lx / 2, cy - ly / 2, z0, z1, step),
        wall(cx - lx / 2, cx + lx / 2, cy + ly / 2, z0, z1, step),
        wall(cy - ly / 2, cy + ly / 2, cx - lx / 2, z0, z1, step)[:, [1, 0, 2]],
        wall(cy - ly / 2, cy + ly / 2, cx + lx / 2, z0, z1, step)[:, [1, 0, 2]],
        plane(cx - lx / 2, cx + lx / 2, cy - ly / 2, cy + ly / 2, z1, step),
    ]
    return np.concatenate(faces)


def pole(cx, cy, height, radius=0.08, step=0.04):
    z = np.arange(0.0, height, step)
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    zz, aa = np.meshgrid(z, a, indexing="ij")
    return np.column_stack([cx + radius * np.cos(aa.ravel()), cy + radius * np.sin(aa.ravel()), zz.ravel()])


def bush(cx, cy, radius=1.0, n=6000):
    d = RNG.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = radius * RNG.random(n) ** (1 / 3)
    return np.array([cx, cy, radius + 0.1]) + d * r[:, None]


@pytest.fixture(scope="module")
def street():
    """A 30 x 16 m plane with a long wall, a car-sized box, a pole and a bush; labels per point."""
    parts = [
        (plane(-15, 15, -8, 8), L.GROUND),
        (wall(-15, 15, 7.5, 0.0, 8.0), L.BUILDING),
        (box(0.0, -2.0, 4.5, 1.8, 0.3, 1.5), L.VEHICLE),
        (pole(8.0, -5.0, 4.0), L.POLE),
        (bush(-8.0, -4.0), L.VEGETATION),
    ]
    pts = np.concatenate([p for p, _ in parts])
    ref = np.concatenate([np.full(len(p), c, np.uint8) for p, c in parts])
    return pts, ref


# ---- voxels and metrics -------------------------------------------------------------------


def test_voxel_grid_counts_coords_neighbours_components():
    pts = np.array([[0.1, 0.1, 0.1], [0.2, 0.3, 0.4], [1.1, 0.1, 0.1], [5.5, 5.5, 5.5], [-0.1, 0.0, 0.0]])
    g = VoxelGrid.build(pts, 1.0)
    assert g.n_voxels == 4
    assert g.voxel[0] == g.voxel[1] != g.voxel[2]
    np.testing.assert_array_equal(g.coords[g.voxel[4]], [-1, 0, 0])
    assert g.counts[g.voxel[0]] == 2
    # neighbourhood sums: the voxel at the origin sees itself (2), (1,0,0) (1) and (-1,0,0) (1)
    np.testing.assert_array_equal(g.neighbourhood_sum(g.counts)[g.voxel[[0, 2, 3, 4]]], [4, 3, 1, 3])
    comp = g.components()
    assert comp[g.voxel[0]] == comp[g.voxel[2]] == comp[g.voxel[4]] != comp[g.voxel[3]]


def test_voxel_grid_grows_its_table():
    pts = RNG.uniform(-50, 50, size=(20000, 3))
    g = VoxelGrid.build(pts, 0.5)
    keys = np.floor(pts / 0.5).astype(np.int64)
    assert g.n_voxels == len(np.unique(keys, axis=0))
    np.testing.assert_array_equal(g.coords[g.voxel], keys)


@settings(max_examples=15, deadline=None)
@given(
    n=st.integers(0, 3000),
    spread=st.sampled_from([2.0, 30.0, 1e7]),
    flat=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
)
def test_merge_walk_neighbours_equal_the_hash_probes(n, spread, flat, seed):
    """The sorted-key merge walk lists the same neighbours in the same order as the 27 probes,
    so sums, components and region growing are bit-identical (also over huge extents)."""
    from prc_slam.util.voxels import _hash_neighbours, _merge_neighbours, radix_argsort

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-spread, spread, size=(n, 3))
    if flat:
        pts[:, 2] = rng.uniform(0, 1.0, n)
    g = VoxelGrid.build(pts, 0.5)
    hs, hn = _hash_neighbours(g.table, g.coords)
    ms, mn = _merge_neighbours(g.coords)
    extent = (g.coords.max(axis=0) - g.coords.min(axis=0) + 3).astype(float) if n else np.ones(3)
    if np.prod(extent) >= 2.0**62:  # linear keys would overflow int64: no lists, the grid probes
        assert len(ms) == 0
        import prc_slam.util.voxels as V

        V.MERGE_MIN_VOXELS, keep = 0, V.MERGE_MIN_VOXELS
        try:
            ms, mn = g.neighbour_lists()  # falls back to the probes
        finally:
            V.MERGE_MIN_VOXELS = keep
    np.testing.assert_array_equal(ms, hs)
    np.testing.assert_array_equal(mn, hn)
    full = g.neighbours(1)
    np.testing.assert_array_equal(hn, full[full >= 0])  # row-major: each voxel's list in probe order
    keys = rng.integers(0, 2**40, size=n)
    np.testing.assert_array_equal(keys[radix_argsort(keys)], np.sort(keys))


def test_large_grid_sums_components_and_segments_as_with_probes():
    from prc_slam.util.voxels import _components, _neighbourhood_sum

    pts = np.concatenate([RNG.uniform([0, 0, 0], [60, 60, 0.5], (60000, 3)), RNG.uniform(-5, 70, (8000, 3))])
    g = VoxelGrid.build(pts, 0.4)
    assert g.n_voxels > 20_000  # the merge-walk path
    vals = RNG.random((g.n_voxels, 4))
    probes = _neighbourhood_sum(g.table, g.coords, vals, 1)
    np.testing.assert_array_equal(g.neighbourhood_sum(vals), probes)  # one merge walk
    g.neighbour_lists()
    np.testing.assert_array_equal(g.neighbourhood_sum(vals), probes)  # on the lists
    np.testing.assert_array_equal(g.components(), _components(g.table, g.coords))
    normals = RNG.normal(size=(g.n_voxels, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[::7] = [0, 0, 1]
    curv = RNG.random(g.n_voxels) * 0.1
    a = M.region_growing(normals, curv, g.neighbours(1), 0.9, 0.05)
    b = M.region_growing_lists(normals, curv, *g.neighbour_lists(), 0.9, 0.05)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]


def test_flat_grid_is_the_grid_of_the_points_on_z_0():
    pts = RNG.uniform(-20, 20, size=(5000, 3))
    a = VoxelGrid.build(pts, 0.7, flat=True)
    b = VoxelGrid.build(np.column_stack([pts[:, :2], np.zeros(len(pts))]), 0.7)
    for x, y in zip((a.voxel, a.coords, a.table, a.counts), (b.voxel, b.coords, b.table, b.counts), strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("scale", [1.0, 1e9])
def test_compact_build_is_the_int64_build(scale):
    """The int32 build gives the int64 build's voxels, order and table slots; voxel
    coordinates beyond int32 (scale 1e9 at 0.3 m) take the int64 build, same grid."""
    from prc_slam.util.voxels import _build, voxel_counts

    pts = RNG.normal(0, 5, size=(6000, 3)) * scale
    pts[1000:2000] = pts[999]  # runs in one voxel (the previous-point shortcut)
    g = VoxelGrid.build(pts, 0.3)
    voxel, coords, table = _build(pts, 1.0 / 0.3, False, 0.0)
    np.testing.assert_array_equal(g.voxel, voxel)
    np.testing.assert_array_equal(g.coords, coords)
    np.testing.assert_array_equal(g.table, table)
    assert g.table.dtype == (np.int32 if scale == 1.0 else np.int64)
    for shift in (0.0, 0.5):
        np.testing.assert_array_equal(voxel_counts(pts, 0.3, shift), VoxelGrid.build(pts + shift, 0.3).counts)


@pytest.mark.parametrize("spread", [40.0, 1e5])
def test_flat_grid_through_a_dense_plane_or_the_hash(monkeypatch, spread):
    """A compact x-y box goes through the dense plane, a sparse one (two clusters far apart)
    through the hash: the same cells either way, and the planar kernels answer the same."""
    import prc_slam.util.voxels as V
    from prc_slam.mapclass.objects import height_above_ground, under_crown

    pts = RNG.uniform(-20, 20, size=(4000, 3))
    pts[::2, :2] += spread
    ground = pts[::3].copy()
    crown = RNG.random(len(pts)) < 0.2
    a = VoxelGrid.build(pts, 0.9, flat=True)
    assert (a.plane[0].size > 0) == (spread < 1000)
    flat = VoxelGrid.build(np.column_stack([pts[:, :2], np.zeros(len(pts))]), 0.9)
    for x, y in zip(
        (a.voxel, a.coords, a.table, a.counts), (flat.voxel, flat.coords, flat.table, flat.counts), strict=True
    ):
        np.testing.assert_array_equal(x, y)
    hag, crowned = height_above_ground(pts, ground, 1.3, 2), under_crown(pts, crown, 0.9, 1)
    monkeypatch.setattr(V, "PLANE_CELLS_PER_POINT", -1e12)  # every flat grid through the hash
    b = VoxelGrid.build(pts, 0.9, flat=True)
    assert b.plane[0].size == 0
    np.testing.assert_array_equal(a.voxel, b.voxel)
    np.testing.assert_array_equal(hag, height_above_ground(pts, ground, 1.3, 2))
    np.testing.assert_array_equal(crowned, under_crown(pts, crown, 0.9, 1))
    # hand check of the height: a point over its own ground cell, ground at z = 1 there
    g = np.array([[0.2, 0.2, 1.0], [0.4, 0.3, 1.0]])
    np.testing.assert_allclose(height_above_ground(np.array([[0.3, 0.3, 3.5]]), g, 1.0, 1), [2.5])


def test_local_density_hand_computed():
    # 54 points in voxel (0,0,0) and 27 in (1,0,0), voxel side 0.5 m: each voxel's 3x3x3
    # neighbourhood holds 81 points in 27 * 0.125 m^3
    pts = np.concatenate([np.full((54, 3), 0.25), np.tile([0.75, 0.25, 0.25], (27, 1))])
    density, _ = M.local_density(pts, 0.5)
    np.testing.assert_allclose(density, 81 / (27 * 0.125))


def test_normals_curvature_and_degenerate_cases():
    flat = plane(0, 1, 0, 1, step=0.1)
    sums = M._voxel_moments(flat, np.zeros(3), np.zeros(len(flat), np.int64), 1)
    n, c = M._normals_from_sums(sums)
    assert abs(abs(n[0, 2]) - 1) < 1e-3 and c[0] < 1e-3
    line = np.column_stack([np.linspace(0, 1, 20), np.zeros(20), np.zeros(20)])
    two = np.zeros((2, 3))
    for pts in (line, two, np.zeros((5, 3))):
        n, c = M._normals_from_sums(M._voxel_moments(pts, np.zeros(3), np.zeros(len(pts), np.int64), 1))
        assert np.isnan(n).all() and c[0] == 1.0


@settings(max_examples=60, deadline=None)
@given(
    w=st.lists(st.one_of(st.just(0.0), st.floats(1e-9, 10.0)), min_size=3, max_size=3),  # m^2
    tie=st.sampled_from([None, (0, 1), (1, 2), (0, 2)]),
    seed=st.integers(0, 2**31 - 1),
)
def test_jacobi_eigh3_agrees_with_lapack(w, tie, seed):
    """The 3x3 Jacobi solver of the normals gives LAPACK's eigenvalues and (up to sign, where
    the smallest one is simple) its smallest eigenvector, on random rotations of given spectra
    (repeated eigenvalues included)."""
    w = np.array(w)
    if tie is not None:
        w[tie[1]] = w[tie[0]]
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    cov = (q * w) @ q.T
    cov = 0.5 * (cov + cov.T)
    a, v, ev = cov.copy(), np.empty((3, 3)), np.empty(3)
    assert M._eigh3(a, v, ev)
    ref_w, ref_v = np.linalg.eigh(cov)
    scale = max(np.abs(w).max(), 1e-300)
    np.testing.assert_allclose(ev, ref_w, atol=1e-13 * scale)
    np.testing.assert_allclose(v.T @ v, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(cov @ v, v * ev, atol=1e-12 * scale)
    if ref_w[1] - ref_w[0] > 1e-6 * scale:
        assert abs(abs(v[:, 0] @ ref_v[:, 0]) - 1) < 1e-9


def test_region_growing_splits_perpendicular_planes_and_isolates_missing_normals():
    normals = np.array([[0, 0, 1], [0, 0, 1], [0.0, 0.05, 1], [1, 0, 0], [1, 0, 0], [np.nan] * 3], float)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    curvature = np.array([0.0, 0.01, 0.01, 0.0, 0.01, 1.0])
    # a chain 0-1-2-3-4-5
    nb = np.array([[1, -1], [0, 2], [1, 3], [2, 4], [3, 5], [4, -1]])
    seg, n = M.region_growing(normals, curvature, nb, np.cos(np.radians(8)), 0.05)
    assert n == 3
    assert seg[0] == seg[1] == seg[2] != seg[3] == seg[4] != seg[5]


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(0, 20000),
    levels=st.integers(1, 10**9),
    extra=st.lists(st.sampled_from([0.0, -0.0, np.inf, 1e-300, 5e-324, 1.0]), max_size=50),
    seed=st.integers(0, 2**31 - 1),
)
def test_stable_argsort_is_the_mergesort(n, levels, extra, seed):
    """The radix argsort of the seeds' curvature keeps ties in input order like mergesort."""
    rng = np.random.default_rng(seed)
    key = np.r_[rng.integers(0, levels, n) / levels * 0.1, extra]
    rng.shuffle(key)
    np.testing.assert_array_equal(M.stable_argsort(key), np.argsort(key, kind="mergesort"))


def test_region_growing_stops_at_high_curvature():
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    nb = np.array([[1, -1], [0, 2], [1, -1]])
    # unit 1 joins 0 but may not seed (curvature above the limit): unit 2 starts its own segment
    seg, n = M.region_growing(normals, np.array([0.0, 0.5, 0.01]), nb, 0.99, 0.05)
    assert seg[0] == seg[1] != seg[2] and n == 2


def test_verticality_hand_computed():
    normals = np.array([[1, 0, 0], [0, 1, 0.1], [0, 0, 1], [np.nan] * 3, [0, 0, 1]], float)
    # 80 deg to up <=> |n_z| < cos 80 = 0.1736; (0, 1, 0.1) unnormalised has n_z 0.1 -> facing
    v = M.verticality(normals, np.array([0, 0, 0, 0, 1]), 2)
    np.testing.assert_allclose(v, [0.5, 0.5, 0.5, 0.5, 0.0])


def test_segment_density_counts_distinct_segments_in_the_neighbourhood():
    pts = np.array([[0.5, 0.5, 0.5], [0.6, 0.5, 0.5], [1.5, 0.5, 0.5], [5.5, 0.5, 0.5]])
    seg = np.array([0, 1, 1, 2])
    density, grid = segment_density_pair = M.segment_density(pts, seg, 1.0)
    assert segment_density_pair[1] is grid
    # voxel (0,0,0): segments {0, 1} + neighbour (1,0,0) {1} -> 2; (1,0,0) -> 2; (5,0,0) -> 1
    np.testing.assert_array_equal(density[grid.voxel], [2, 2, 2, 1])


def test_segment_voxels_and_compact():
    seg, n = compact(np.array([7, 7, 3, 9, 3]))
    np.testing.assert_array_equal(seg, [0, 0, 1, 2, 1])
    assert n == 3
    pts = np.array([[0.1, 0, 0], [0.2, 0, 0], [1.1, 0, 0], [0.1, 0, 0], [2.5, 0, 0]])
    np.testing.assert_array_equal(segment_voxels(pts, seg, 3, 1.0), [1, 2, 1])  # seg 0: both in x = 0


@settings(max_examples=20, deadline=None)
@given(n=st.integers(1, 400), n_seg=st.integers(1, 30), limit=st.floats(0.2, 3.0), seed=st.integers(0, 2**31 - 1))
def test_segment_voxels_and_grid_distance_match_their_definitions(n, n_seg, limit, seed):
    """Distinct voxels per segment = distinct (voxel, segment) pairs; the one-grid building
    distance = a kd-tree between separately built grids of the two sets."""
    from scipy.spatial import cKDTree

    from prc_slam.mapclass.objects import distance_to, grid_distance

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-3, 3, size=(n, 3))
    seg = rng.integers(0, n_seg, n)
    g = VoxelGrid.build(pts, 0.33)
    pairs = np.unique(np.column_stack([g.voxel, seg]), axis=0)
    np.testing.assert_array_equal(segment_voxels(pts, seg, n_seg, 0.33), np.bincount(pairs[:, 1], minlength=n_seg))
    query, target = rng.random(n) < 0.6, rng.random(n) < 0.3
    d = grid_distance(g, query, target, limit)
    if target.any():
        tg, qg = VoxelGrid.build(pts[target], 0.33), VoxelGrid.build(pts[query], 0.33)
        ref, _ = cKDTree((tg.coords + 0.5) * 0.33).query((qg.coords + 0.5) * 0.33, distance_upper_bound=limit)
        np.testing.assert_array_equal(d, ref[qg.voxel])
        np.testing.assert_array_equal(distance_to(pts[query], pts[target], 0.33, limit), ref[qg.voxel])
    else:
        assert np.isinf(d).all() and len(d) == query.sum()


# ---- classes ------------------------------------------------------------------------------


def test_ground_keeps_slopes_and_curbs_rejects_box_tops(street):
    pts, ref = street
    ground = detect_ground(pts)
    assert ground[ref == L.GROUND].mean() > 0.99
    box_top = (ref == L.VEHICLE) & (pts[:, 2] > 1.4)
    assert not ground[box_top].any()
    # a 10 % slope with a 12 cm curb is ground everywhere
    slope = np.concatenate([plane(0, 20, 0, 5, slope=0.1), plane(0, 20, 5, 8, z=0.12, slope=0.1)])
    assert detect_ground(slope).mean() > 0.99


def _votes_along_each_line(zmin, zlocal, cell, max_slope, max_step, max_above_local):
    """Sec. 4.1's scan lines walked one by one from their first cell (the definition)."""
    from prc_slam.mapclass.ground import DIRECTIONS

    nx, ny = zmin.shape
    votes = np.zeros((nx, ny), np.int64)
    for dx, dy in DIRECTIONS:
        step = cell * np.sqrt(dx * dx + dy * dy)
        for sx in range(nx):
            for sy in range(ny):
                if 0 <= sx - dx < nx and 0 <= sy - dy < ny:
                    continue  # not the first cell of its line
                x, y, zg, dist = sx, sy, np.nan, 0.0
                while 0 <= x < nx and 0 <= y < ny:
                    dist += step
                    z = zmin[x, y]
                    if np.isfinite(z):
                        ok = z - zlocal[x, y] <= max_above_local
                        if ok and not np.isnan(zg):
                            ok = z - zg <= max_slope * dist + max_step
                        if ok:
                            votes[x, y] += 1
                            zg, dist = z, 0.0
                    x, y = x + dx, y + dy
    return votes


@settings(max_examples=30, deadline=None)
@given(nx=st.integers(1, 12), ny=st.integers(1, 12), empty=st.floats(0, 0.8), seed=st.integers(0, 2**31 - 1))
def test_scan_line_sweep_equals_walking_each_line(nx, ny, empty, seed):
    from scipy.ndimage import minimum_filter

    from prc_slam.mapclass.ground import scan_line_votes

    rng = np.random.default_rng(seed)
    bumps = rng.normal(0, 0.3, (nx, ny)) * (rng.random((nx, ny)) < 0.2)
    zmin = np.cumsum(rng.normal(0, 0.15, (nx, ny)), axis=0) + bumps
    zmin[rng.random((nx, ny)) < empty] = np.inf
    zlocal = minimum_filter(zmin, size=3, mode="nearest")
    args = (zmin, zlocal, 0.5, 0.3, 0.1, 0.5)
    np.testing.assert_array_equal(scan_line_votes(*args), _votes_along_each_line(*args))


def test_ground_majority_vote_needs_five_of_eight_directions():
    from prc_slam.mapclass.ground import scan_line_votes

    zmin = np.zeros((5, 5))
    zmin[2, 2] = 0.5  # a 0.5 m step on flat ground: every scan line rejects it
    votes = scan_line_votes(zmin, np.zeros((5, 5)), 0.5, 0.3, 0.1, 1.0)
    assert votes[2, 2] == 0 and (np.delete(votes.ravel(), 12) == 8).all()
    zmin[2, 2] = 0.2  # within max_slope * 0.5 + max_step from each side's last ground cell
    assert scan_line_votes(zmin, np.zeros((5, 5)), 0.5, 0.3, 0.1, 1.0)[2, 2] == 8


def test_height_above_ground_under_a_car_without_ground_beneath():
    ground = plane(-5, 5, -5, 5, z=1.0)
    ground = ground[np.abs(ground[:, 0]) > 1.0]  # a hole where a car hides the road
    hag = height_above_ground(np.array([[0.0, 0.0, 1.5], [30.0, 30.0, 1.0]]), ground)
    assert abs(hag[0] - 0.5) < 0.01 and np.isnan(hag[1])


def test_grid_distance_few_queries_against_many_targets():
    """Few queries: the kd-tree holds only the targets near them; distances unchanged."""
    from scipy.spatial import cKDTree

    from prc_slam.mapclass.objects import grid_distance

    wall_pts = wall(0, 30, 0.0, 0.0, 10.0)  # 60 k targets
    probes = np.array([[5.0, 1.0, 2.0], [5.0, 1.4, 2.0], [15.0, 2.9, 5.0], [15.0, 4.0, 5.0], [-3.0, 0.0, 1.0]])
    pts = np.concatenate([wall_pts, probes])
    query = np.r_[np.zeros(len(wall_pts), bool), np.ones(len(probes), bool)]
    g = VoxelGrid.build(pts, 0.33)
    for limit in (1.5, 3.0):
        d = grid_distance(g, query, ~query, limit)
        tg, qg = VoxelGrid.build(wall_pts, 0.33), VoxelGrid.build(probes, 0.33)
        ref, _ = cKDTree((tg.coords + 0.5) * 0.33).query((qg.coords + 0.5) * 0.33, distance_upper_bound=limit)
        np.testing.assert_array_equal(d, ref[qg.voxel])
        assert np.isfinite(d).sum() >= 2 and np.isinf(d).sum() >= 1


@settings(max_examples=20, deadline=None)
@given(
    n=st.integers(1, 600),
    cell=st.sampled_from([0.7, 1.0, 2.5]),
    radius=st.integers(1, 4),
    seed=st.integers(0, 2**31 - 1),
)
def test_nearest_cell_centre_is_the_kd_tree_query(n, cell, radius, seed):
    """The grid search finds the cell a kd-tree on the centres finds (distance_upper_bound is
    strict), on clouds with holes and points far outside."""
    from scipy.spatial import cKDTree

    from prc_slam.mapclass.objects import nearest_cell_centre

    rng = np.random.default_rng(seed)
    ground = rng.uniform(-10, 10, size=(n, 3))
    ground = ground[np.hypot(ground[:, 0], ground[:, 1]) > 4]  # a hole in the middle
    pts = rng.uniform(-20, 20, size=(300, 3))
    if len(ground) == 0:
        return
    grid = VoxelGrid.build(np.column_stack([ground[:, :2], np.zeros(len(ground))]), cell)
    pts = np.concatenate([pts, np.round(pts / (0.5 * cell)) * (0.5 * cell)])  # on cell borders: ties
    j = nearest_cell_centre(grid, pts, cell, radius * cell)
    centres = (grid.coords[:, :2] + 0.5) * cell
    d, ref = cKDTree(centres).query(pts[:, :2], distance_upper_bound=radius * cell)
    np.testing.assert_array_equal(j >= 0, np.isfinite(d))
    found = j >= 0
    ours = np.hypot(*(pts[found, :2] - centres[j[found]]).T)
    np.testing.assert_allclose(ours, d[found], rtol=1e-12, atol=1e-12)  # the nearest distance
    np.testing.assert_array_equal(j[:300], np.where(np.isfinite(d[:300]), ref[:300], -1))  # no ties: same cell


def test_buildings_take_the_wall_and_small_segments_on_it_not_far_ones():
    w = wall(0, 20, 0, 0, 6)
    frame = box(10, -0.3, 1.0, 0.2, 2.0, 3.0, step=0.05)  # a window ledge 0.3 m off the wall
    far = box(10, -8, 1.0, 0.2, 2.0, 3.0, step=0.05)
    pts = np.concatenate([w, frame, far])
    seg = np.concatenate([np.zeros(len(w)), np.ones(len(frame)), np.full(len(far), 2)]).astype(np.int64)
    vert = np.concatenate([np.ones(len(w)), np.zeros(len(frame) + len(far))])
    b = detect_buildings(pts, seg, vert, None, min_height=2.0, min_reach=6.0)
    assert b[: len(w)].all() and b[len(w) : len(w) + len(frame)].all() and not b[-len(far) :].any()
    # a low, car-long vertical segment is a building only in paper mode (no height / reach guard)
    car_side = wall(0, 4.5, -10, 0.3, 1.4)
    pts2 = np.concatenate([w, car_side])
    seg2 = np.r_[np.zeros(len(w)), np.ones(len(car_side))].astype(np.int64)
    v2 = np.ones(len(pts2))
    ours = detect_buildings(pts2, seg2, v2, None, min_segment_voxels=20, min_height=2.0, min_reach=6.0)
    assert not ours[len(w) :].any()
    assert detect_buildings(pts2, seg2, v2, None, min_segment_voxels=20)[len(w) :].all()


def test_buildings_spare_marks_keep_hedges_off_the_facade():
    w = wall(0, 20, 0, 0, 6)
    hedge = bush(10, -1.0, radius=0.8)
    pts = np.concatenate([w, hedge])
    seg = np.r_[np.zeros(len(w)), 1 + np.arange(len(hedge))].astype(np.int64)
    vert = np.r_[np.ones(len(w)), np.zeros(len(hedge))]
    spare = np.r_[np.zeros(len(w), bool), np.ones(len(hedge), bool)]
    paper = detect_buildings(pts, seg, vert, None, near=0.0)
    ours = detect_buildings(pts, seg, vert, None, near=0.0, spare=spare)
    assert paper[len(w) :].mean() > 0.9 and not ours[len(w) :].any()


def test_vehicles_by_dimensions_and_ground_contact(street):
    pts, ref = street
    ground = pts[ref == L.GROUND]
    car = box(0, 0, 4.5, 1.8, 0.3, 1.5)
    floating = box(0, 10, 4.5, 1.8, 2.5, 3.7)
    bus_long = box(0, 20, 12.0, 2.4, 0.3, 3.0)
    pts2 = np.concatenate([car, floating, bus_long])
    seg = np.concatenate([np.full(len(car), 0), np.full(len(floating), 1), np.full(len(bus_long), 2)])
    v = detect_vehicles(pts2, seg, ground)
    assert v[: len(car)].all() and not v[len(car) :].any()
    # cut into 0.3 m slices (one segment each, each too flat for a car), found as a group only
    slices = np.floor((car[:, 2] - 0.3) / 0.3).astype(np.int64)
    assert not detect_vehicles(car, slices, ground, small_segment_points=1).any()
    assert detect_vehicles(car, slices, ground, small_segment_points=1, group_voxel=0.3).all()


def test_posts_pillars_taller_than_1_5_m_and_slim():
    p = pole(0, 0, 3.0)
    stump = pole(5, 0, 1.0)
    w = wall(10, 15, 0, 0, 3)
    pts = np.concatenate([p, stump, w])
    seg = np.concatenate([np.zeros(len(p)), np.ones(len(stump)), np.full(len(w), 2)]).astype(np.int64)
    post = detect_posts(pts, seg, small_segment_points=1)
    assert post[: len(p)].mean() > 0.9 and not post[len(p) :].any()


def test_vegetation_where_segments_are_many(street):
    pts, ref = street
    rest = ref != L.GROUND
    p = pts[rest]
    # one segment per point in the bush (what region growing yields on foliage), one per object else
    seg = np.where(ref[rest] == L.VEGETATION, 10 + np.arange(len(p)), ref[rest]).astype(np.int64)
    veg = detect_vegetation(p, seg, p)
    r = ref[rest]
    assert veg[r == L.VEGETATION].mean() > 0.8 and veg[r != L.VEGETATION].mean() < 0.02


# ---- the whole pipeline and bad input -----------------------------------------------------


def test_classify_map_constructed_street(street):
    pts, ref = street
    res = classify_map(pts)
    assert len(res.labels) == len(pts)
    # the box's sharp roof edges break into many small segments, which the vegetation test flags
    # in so small a scene: the roof's rim stays unclassified (recall 0.79)
    for code, recall in [(L.GROUND, 0.95), (L.BUILDING, 0.9), (L.VEHICLE, 0.75), (L.POLE, 0.7), (L.VEGETATION, 0.6)]:
        assert (res.labels[ref == code] == code).mean() >= recall, L.CODE_TO_NAME[code]
    assert set(res.seconds) >= {"density", "normals", "segmentation", "ground", "buildings", "vegetation"}


def test_bad_input_empty_single_nan_and_sparse():
    assert len(classify_map(np.zeros((0, 3))).labels) == 0
    with pytest.warns(DensityWarning, match="100.0 % of the points"):
        one = classify_map(np.array([[1.0, 2.0, 3.0]]))
    assert one.labels.tolist() == [L.NOISE]  # a lone point is under the relative threshold's floor (2 points)
    pts = plane(0, 5, 0, 5)
    pts[[3, 10]] = np.nan
    pts[20] = [np.inf, 0, 0]
    res = classify_map(pts)
    assert res.nonfinite == 3 and (res.labels[[3, 10, 20]] == L.NO_RETURN).all()
    assert (res.labels[np.isfinite(pts).all(axis=1)] == L.GROUND).mean() > 0.95
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        classify_map(np.zeros((4, 2)))
    # all points identical: degenerate normals, still one label each
    same = classify_map(np.ones((500, 3)))
    assert len(same.labels) == 500 and np.isnan(same.segment).sum() == 0


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(0, 400),
    spread=st.floats(0.1, 50.0),
    nan_share=st.floats(0.0, 0.3),
    seed=st.integers(0, 2**16),
)
def test_one_label_per_input_point(n, spread, nan_share, seed):
    rng = np.random.default_rng(seed)
    pts = rng.normal(0, spread, (n, 3))
    pts[rng.random(n) < nan_share] = np.nan
    with warnings.catch_warnings():  # random clouds may be too sparse for their own threshold: said, not tested here
        warnings.simplefilter("ignore", DensityWarning)
        res = classify_map(pts)
    allowed = {L.NO_RETURN, L.UNCLASSIFIED, L.GROUND, L.BUILDING, L.VEHICLE, L.POLE, L.VEGETATION, L.NOISE}
    assert res.labels.shape == (n,) and set(np.unique(res.labels).tolist()) <= allowed
    assert ((res.labels == L.NO_RETURN) == ~np.isfinite(pts).all(axis=1)).all()


def test_density_threshold_limits():
    pts = plane(0, 5, 0, 5)
    assert (classify_map(pts, MapClassConfig(density_relative=False, min_density=0.0)).labels != L.NOISE).all()
    with pytest.warns(DensityWarning, match="mobile-mapping figure"):
        dense = classify_map(pts, MapClassConfig(density_relative=False, min_density=1e12))
    assert (dense.labels == L.NOISE).all()


def test_tiled_equals_untiled_inside_one_tile_and_keeps_every_point(street, tmp_path):
    pts = street[0] + [50.0, 50.0, 0.0]  # inside the tile [0, 100)^2
    whole = classify_map(pts).labels
    tiled, seconds = classify_tiled(array_chunks(pts, 50_000), tile=100.0, margin=5.0, workdir=tmp_path)
    np.testing.assert_array_equal(tiled, whole)
    assert "normals" in seconds and not list(tmp_path.iterdir())  # spill files removed
    bad = pts.copy()
    bad[5] = np.nan
    labels, _ = classify_tiled(array_chunks(bad, 10_000), tile=10.0, margin=3.0)
    assert len(labels) == len(bad) and labels[5] == L.NO_RETURN
    border = np.mean(labels[np.isfinite(bad).all(axis=1)] != whole[np.isfinite(bad).all(axis=1)])
    assert border < 0.1  # 10 m tiles cut the wall and the car; the margin keeps most labels


def test_to_world_interpolates_between_frame_poses():
    from scipy.spatial.transform import Rotation

    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, 3] = [2.0, 0.0, 0.0]
    poses[1, :3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    p = np.array([[1.0, 0.0, 0.0]] * 3)
    w = to_world(p, np.array([0.0, 0.5, 2.0]), np.array([0.0, 1.0]), poses)
    half = Rotation.from_euler("z", 45, degrees=True).apply([1.0, 0, 0]) + np.array([1.0, 0, 0])
    np.testing.assert_allclose(w, [[1, 0, 0], half, [2, 1, 0]], atol=1e-12)


# ---- simulated urban map ------------------------------------------------------------------


@pytest.fixture(scope="module")
def urban_map():
    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.mapclass import accumulate
    from prc_slam.scan import Scan

    sim = Simulator(SimConfig(frames=30, seed=2))
    frames = [sim.frame(i) for i in range(30)]

    def scans():
        for i, f in enumerate(frames):
            s = Scan(f.ranges, sim.sensor.model, timestamps=f.slot_times, gt_labels=f.labels, gt_instance=f.instance)
            yield i, s, {"ref": s.reference_labels(), "inst": s.per_point(s.gt_instance)}

    return accumulate(scans(), np.array([f.pose for f in frames]), np.array([f.time for f in frames]))


def test_simulated_urban_map(urban_map):
    from prc_slam.jobs.mapclass import score_map

    res = classify_map(urban_map.points)
    s = score_map(res.labels, urban_map.attributes["ref"], urban_map.attributes["inst"])
    pc = s["per_class"]
    # measured on this drive (30 hdl64 frames, seed 2): ground: 0.97 / 0.99, building 0.99 / 0.90,
    # vehicle 0.99 / 0.91
    assert pc["ground"]["precision"] > 0.95 and pc["ground"]["recall"] > 0.95
    assert pc["building"]["precision"] > 0.95 and pc["building"]["recall"] > 0.85
    assert pc["vehicle"]["precision"] > 0.95 and pc["vehicle"]["recall"] > 0.85
    assert s["objects"]["vehicle"]["found"] >= 1 and s["objects"]["vehicle"]["present"] >= 5


def test_stems_under_a_crown_are_not_posts():
    from prc_slam.mapclass.objects import under_crown

    stem = pole(0, 0, 4.0)
    crown = bush(0.3, 0.0, radius=1.5) + np.array([0, 0, 3.5])  # foliage from 3.5 m up, right above the stem
    lamp = pole(10, 0, 4.0)
    pts = np.concatenate([stem, crown, lamp])
    foliage = np.r_[np.zeros(len(stem), bool), np.ones(len(crown), bool), np.zeros(len(lamp), bool)]
    under = under_crown(pts, foliage)
    assert under[: len(stem)].all() and not under[-len(lamp) :].any()
    # end to end: the stem goes to vegetation, the lamp post stays a post
    ground = plane(-5, 15, -5, 5)
    res = classify_map(np.concatenate([ground, pts]))
    lab = res.labels[len(ground) :]
    assert (lab[: len(stem)] == L.VEGETATION).mean() > 0.6 and (lab[-len(lamp) :] == L.POLE).mean() > 0.8


@settings(max_examples=40, deadline=None)
@given(nx=st.integers(1, 30), ny=st.integers(1, 30), half=st.integers(0, 8), seed=st.integers(0, 2**31 - 1))
def test_minimum_window_is_scipys_minimum_filter(nx, ny, half, seed):
    from scipy.ndimage import minimum_filter

    from prc_slam.mapclass.ground import minimum_window

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(nx, ny))
    a[rng.random((nx, ny)) < 0.4] = np.inf  # empty terrain cells
    w = 2 * half + 1
    np.testing.assert_array_equal(minimum_window(a, w), minimum_filter(a, size=w, mode="nearest"))


def test_column_mean_is_numpys_mean_bit_for_bit():
    pts = RNG.normal(3e5, 1e3, size=(100_003, 3))
    assert M._column_mean(pts).tobytes() == pts.mean(axis=0).tobytes()
    assert M._column_mean(pts[::3]).tobytes() == np.ascontiguousarray(pts[::3]).mean(axis=0).tobytes()


def test_voxel_normals_from_lists_are_the_normals_of_the_summed_moments():
    """The fused kernel (sums over the neighbour lists, then the eigen solver) gives the same
    normals and curvatures as summing the moments first, bit for bit."""
    pts = np.concatenate([RNG.uniform(0, 8, (3000, 3)) * [1, 1, 0.05], RNG.normal(4, 1.0, (2000, 3))])
    grid, normals, curvature = M.voxel_normals(pts, 0.4)
    sums = M._voxel_moments(pts, pts.mean(axis=0), grid.voxel, grid.n_voxels)
    n2, c2 = M._normals_from_sums(grid.neighbourhood_sum(sums))
    np.testing.assert_array_equal(normals, n2)
    np.testing.assert_array_equal(curvature, c2)
    assert np.isfinite(normals[:, 0]).mean() > 0.5


def test_subset_grid_is_the_grid_of_the_subset():
    pts = RNG.normal(0, 3, size=(5000, 3))
    grid = VoxelGrid.build(pts, 0.5)
    for rows in (np.flatnonzero(RNG.random(len(pts)) < 0.7), np.arange(len(pts)), np.zeros(0, np.int64)):
        a, b = grid.subset(rows), VoxelGrid.build(pts[rows], 0.5)
        for x, y in zip((a.voxel, a.coords, a.counts, a.table), (b.voxel, b.coords, b.counts, b.table), strict=True):
            np.testing.assert_array_equal(x, y)
