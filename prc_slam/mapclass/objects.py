"""Object classes of paper 004, Sec. 4.2-4.5: buildings, vehicles, posts, vegetation.

Each step takes the points the earlier steps left (``points``, their ``segment`` ids and, where
needed, metrics) and returns a mask over them; segment statistics are computed over those
points only.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from prc_slam.mapclass.metrics import segment_density
from prc_slam.util.voxels import VoxelGrid, _rehash32, _table_size, find, find_cell, group_members, voxel_counts


@njit(cache=True, nogil=True)
def segment_bounds(segment, points, n_segments):
    """Per-segment min and max of x, y, z: ``(S, 3)`` each (inf/-inf for empty segments)."""
    lo = np.full((n_segments, 3), np.inf)
    hi = np.full((n_segments, 3), -np.inf)
    for i in range(segment.shape[0]):
        s = segment[i]
        for j in range(3):
            v = points[i, j]
            if v < lo[s, j]:
                lo[s, j] = v
            if v > hi[s, j]:
                hi[s, j] = v
    return lo, hi


@njit(cache=True, nogil=True)
def _compact(segment, n_ids):
    new = np.full(n_ids, -1, np.int64)
    out = np.empty(segment.shape[0], np.int64)
    ns = 0
    for i in range(segment.shape[0]):
        s = segment[i]
        if new[s] < 0:
            new[s] = ns
            ns += 1
        out[i] = new[s]
    return out, ns


def compact(segment: np.ndarray) -> tuple[np.ndarray, int]:
    """Renumber non-negative segment ids to 0..S-1 in order of first appearance (O(N))."""
    segment = np.asarray(segment, dtype=np.int64)
    if len(segment) == 0:
        return segment, 0
    return _compact(segment, int(segment.max()) + 1)


@njit(cache=True, nogil=True)
def _distinct_per_segment(segment, voxel, n_segments, n_voxels):
    """Distinct voxels per segment: the points grouped by segment (counting sort, O(N + S)),
    each segment stamps the voxels it visits."""
    start, members = group_members(segment, n_segments)
    stamp = np.full(n_voxels, -1, np.int64)
    out = np.zeros(n_segments, np.int64)
    for s in range(n_segments):
        for j in range(start[s], start[s + 1]):
            v = voxel[members[j]]
            if stamp[v] != s:
                stamp[v] = s
                out[s] += 1
    return out


def segment_voxels(
    points: np.ndarray, segment: np.ndarray, n_segments: int, voxel: float, grid: VoxelGrid | None = None
) -> np.ndarray:
    """Number of distinct voxels of side ``voxel`` each segment occupies (O(N)); ``grid``: the
    points' grid of that side when already built."""
    grid = VoxelGrid.build(points, voxel) if grid is None else grid
    seg = np.asarray(segment, dtype=np.int64)
    return _distinct_per_segment(seg, grid.voxel, int(n_segments), grid.n_voxels)


def distance_to(points: np.ndarray, targets: np.ndarray, voxel: float, limit: float) -> np.ndarray:
    """Distance (m) from each point's voxel centre to the nearest voxel holding a target point,
    ``inf`` beyond ``limit`` (the paper's building-voxel distance, Sec. 4.2)."""
    if len(targets) == 0 or len(points) == 0:
        return np.full(len(points), np.inf)
    grid = VoxelGrid.build(np.concatenate([points, targets]), voxel)
    query = np.r_[np.ones(len(points), bool), np.zeros(len(targets), bool)]
    return grid_distance(grid, query, ~query, limit)


def grid_distance(grid: VoxelGrid, query: np.ndarray, target: np.ndarray, limit: float) -> np.ndarray:
    """:func:`distance_to` on one grid of all the points: for the ``query`` points, the
    distance from their voxel's centre to the nearest voxel centre holding a ``target`` point,
    ``inf`` beyond ``limit``. The same distances as building one grid of each set (voxels are
    the same cubes), without building them."""
    if not target.any() or not query.any():
        return np.full(int(np.count_nonzero(query)), np.inf)
    has_target, asked = _mark_voxels(grid.voxel, query, target, grid.n_voxels)
    _, targets = _marked_centres(grid.coords, has_target, grid.size)
    ask, centres = _marked_centres(grid.coords, asked, grid.size)
    # only voxels with a target voxel centre in the 3x3x3 cubes of side ``limit`` around theirs
    # can be closer than ``limit`` (the side is a hair longer, against rounding in the cube
    # index): the kd-tree answers for those alone
    side = limit * (1.0 + 1e-9)
    coarse = VoxelGrid.build(targets, side)
    near = _any_in_cube(coarse.table, coarse.coords, centres, 1.0 / side)
    d = np.full(grid.n_voxels, np.inf)
    if near.any():
        asked_near = centres[near]
        if 4 * len(asked_near) < len(targets):  # few queries: the targets near them suffice
            qgrid = VoxelGrid.build(asked_near, side)
            targets = targets[_any_in_cube(qgrid.table, qgrid.coords, targets, 1.0 / side)]
        # an unbalanced tree of plain nodes: built ~2.5x faster (sliding-midpoint splits, no node
        # shrinking), queried as fast; the nearest distance does not depend on the tree's shape
        tree = cKDTree(targets, balanced_tree=False, compact_nodes=False)
        d[ask[near]], _ = tree.query(asked_near, distance_upper_bound=limit, workers=-1)
    return _gather_marked(grid.voxel, query, d)


@njit(cache=True, nogil=True)
def _mark_voxels(voxel, query, target, n_voxels):
    """Voxels holding a ``target`` point, voxels holding a ``query`` point."""
    has_target = np.zeros(n_voxels, np.bool_)
    asked = np.zeros(n_voxels, np.bool_)
    for i in range(voxel.shape[0]):
        if target[i]:
            has_target[voxel[i]] = True
        if query[i]:
            asked[voxel[i]] = True
    return has_target, asked


def _marked_centres(coords: np.ndarray, marked: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """The marked voxels and their centres, ``(coords[marked] + 0.5) * size`` (the same values),
    in one pass without the temporaries."""
    m = int(np.count_nonzero(marked))
    out, centres = np.empty(m, np.int64), np.empty((m, 3))
    _fill_centres(coords, marked, float(size), out, centres)
    return out, centres


@njit(cache=True, nogil=True)
def _fill_centres(coords, marked, size, out, centres):
    k = 0
    for v in range(marked.shape[0]):
        if marked[v]:
            out[k] = v
            centres[k, 0] = (coords[v, 0] + 0.5) * size
            centres[k, 1] = (coords[v, 1] + 0.5) * size
            centres[k, 2] = (coords[v, 2] + 0.5) * size
            k += 1


@njit(cache=True, nogil=True)
def _gather_marked(voxel, mask, values):
    """``values[voxel[mask]]``."""
    out = np.empty(np.count_nonzero(mask), values.dtype)
    k = 0
    for i in range(voxel.shape[0]):
        if mask[i]:
            out[k] = values[voxel[i]]
            k += 1
    return out


@njit(cache=True, nogil=True, parallel=True)
def _any_in_cube(table, coords, points, inv_size):
    """Whether the 3x3x3 cubes of a grid (side ``1 / inv_size``) around each point's cube hold
    any occupied one."""
    out = np.zeros(points.shape[0], np.bool_)
    for i in prange(points.shape[0]):
        x = np.int64(np.floor(points[i, 0] * inv_size))
        y = np.int64(np.floor(points[i, 1] * inv_size))
        z = np.int64(np.floor(points[i, 2] * inv_size))
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    if find(table, coords, x + dx, y + dy, z + dz) >= 0:
                        out[i] = True
                        break
                if out[i]:
                    break
            if out[i]:
                break
    return out


def detect_buildings(
    points: np.ndarray,
    segment: np.ndarray,
    verticality: np.ndarray,
    min_segment_points: int | None,
    min_verticality: float = 0.6,
    min_height: float = 0.0,
    near: float = 3.0,
    close: float = 1.5,
    close_share: float = 2.0 / 3.0,
    voxel: float = 0.33,
    spare: np.ndarray | None = None,
    min_segment_voxels: int = 50,
    min_reach: float = 0.0,
    roof: np.ndarray | None = None,
    max_roof_verticality: float = 0.4,
    seeds_out: np.ndarray | None = None,
    grid: VoxelGrid | None = None,
) -> np.ndarray:
    """Sec. 4.2, in the paper's four passes (Fig. 3): large segments with mean verticality
    ≥ ``min_verticality`` (blue); points of large segments within ``near`` of them (green);
    segments of any size with ≥ ``close_share`` of their points within ``close`` (orange); large
    segments above building points (roofs, yellow). Not in the paper (both 0 turn it off): the
    first pass also asks a segment to span ``min_height`` or to reach ``min_reach`` horizontally
    (x-y bounding-box diagonal), which keeps car sides out: facades a street-level scanner sees
    only up to 2-3 m are still longer than a car.
    A segment is large with ``min_segment_points`` points (the paper's size) or, when that is
    None, when it occupies ``min_segment_voxels`` voxels of side ``voxel`` (a surface area,
    which does not change with the map's point density).
    ``spare`` (not in the paper; None turns it off) marks points the orange pass must not take
    by segment majority: the classifier passes posts (Sec. 4.4) and foliage
    (:func:`prc_slam.mapclass.metrics.fragmentation`), so that poles, hedges and crowns next to a
    facade are not joined to it. ``grid``: the grid of ``points`` in voxels of side ``voxel``
    when already built.
    """
    seg, ns = compact(segment)
    size = np.bincount(seg, minlength=ns)
    if grid is None or grid.size != voxel or len(grid.voxel) != len(points):
        grid = VoxelGrid.build(points, voxel)
    if min_segment_points is not None:
        large = size >= min_segment_points
    else:
        large = segment_voxels(points, seg, ns, voxel, grid) >= min_segment_voxels
    vert = np.bincount(seg, weights=verticality, minlength=ns) / np.maximum(size, 1)
    lo, hi = segment_bounds(seg, points, ns)
    reach = np.hypot(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1])
    tall_or_long = (hi[:, 2] - lo[:, 2] >= min_height) | (reach >= min_reach)
    core = large & (vert >= min_verticality) & tall_or_long
    if roof is not None:
        roof_share = np.bincount(seg, weights=roof, minlength=ns) / np.maximum(size, 1)
        roof_core = large & (roof_share >= 0.5) & (vert <= max_roof_verticality)
        core |= roof_core
        if seeds_out is not None:
            seeds_out[:] = roof_core[seg]
    building = core[seg]
    # green: points of large segments near the building voxels
    cand = large[seg] & ~building
    if cand.any():
        d = grid_distance(grid, cand, building, near)
        building[np.flatnonzero(cand)[d <= near]] = True
    # orange: whole segments with two thirds of their points close to buildings
    rest = ~building
    if rest.any():
        # segments mostly ``spare`` never join: their points need no distance
        can = None if spare is None else np.bincount(seg, weights=spare, minlength=ns) < 0.5 * size
        ask = rest if can is None else rest & can[seg]
        d = grid_distance(grid, ask, building, close)
        within = np.bincount(seg[ask], weights=d <= close, minlength=ns)
        total = np.bincount(seg[rest], minlength=ns)
        join = (total > 0) & (within >= close_share * total)
        if can is not None:
            join &= can
        building |= join[seg] & rest
    # yellow: large segments above building points (roofs)
    rest = ~building & large[seg]
    if rest.any() and building.any():
        cols = VoxelGrid.build(points, 1.0, flat=True)
        top = _cell_top(cols.voxel, building, points, cols.n_voxels)
        above = (points[:, 2] >= top[cols.voxel] - 1.0) & np.isfinite(top[cols.voxel])
        share = np.bincount(seg[rest], weights=above[rest], minlength=ns) / np.maximum(
            np.bincount(seg[rest], minlength=ns), 1
        )
        building |= (share >= 0.5)[seg] & rest
    return building


def ground_height_grid(ground: np.ndarray, cell: float, radius: int) -> tuple[VoxelGrid, np.ndarray]:
    """Mean ground height per xy cell over its ``(2r+1)^2`` neighbourhood."""
    grid = VoxelGrid.build(ground, cell, flat=True)
    sums = np.column_stack([np.bincount(grid.voxel, weights=ground[:, 2]), grid.counts])
    agg = _planar_sum(grid.plane, grid.probe_table, grid.coords, sums, radius)  # flat: only the z = 0 layer is occupied
    return grid, agg[:, 0] / agg[:, 1]


@njit(cache=True, nogil=True, parallel=True)
def _planar_sum(plane, table, coords, values, radius):
    """:meth:`VoxelGrid.neighbourhood_sum` of a flat grid (every voxel at z = 0): the
    ``(2r+1)^2`` cells of its layer, added in the same order (the other layers are empty);
    cells found through the grid's dense ``plane`` when it has one (:func:`find_cell`)."""
    nv, m = values.shape
    out = np.zeros((nv, m))
    for v in prange(nv):
        for dx in range(-radius, radius + 1):
            for dy in range(-radius, radius + 1):
                u = find_cell(plane, table, coords, coords[v, 0] + dx, coords[v, 1] + dy)
                if u >= 0:
                    for j in range(m):
                        out[v, j] += values[u, j]
    return out


@njit(cache=True, nogil=True)
def _lookup_cells(plane, table, coords, points, cell):
    """Index of the flat grid's cell ``floor(p / cell)`` under each point, -1 where none."""
    out = np.empty(points.shape[0], np.int64)
    for i in range(points.shape[0]):
        x = np.int64(np.floor(points[i, 0] / cell))
        y = np.int64(np.floor(points[i, 1] / cell))
        out[i] = find_cell(plane, table, coords, x, y)
    return out


def height_above_ground(
    points: np.ndarray,
    ground: np.ndarray,
    cell: float = 1.0,
    radius: int = 3,
    heights: tuple[VoxelGrid, np.ndarray] | None = None,
) -> np.ndarray:
    """Height of each point above the mean ground height of the cells beneath and close to it
    (NaN where no ground lies within ``radius`` cells). ``heights``: ``ground_height_grid(ground,
    cell, radius)`` when already made."""
    if len(ground) == 0:
        return np.full(len(points), np.nan)
    grid, gz = heights if heights is not None else ground_height_grid(ground, cell, radius)
    idx = _lookup_cells(grid.plane, grid.probe_table, grid.coords, points, cell)
    out = np.full(len(points), np.nan)
    has = idx >= 0
    out[has] = points[has, 2] - gz[idx[has]]
    # cells beyond the ground grid: nearest ground cell centre closer than radius * cell
    if (~has).any():
        sub = np.flatnonzero(~has)
        j = nearest_cell_centre(grid, np.take(points, sub, axis=0), cell, radius * cell)
        ok = j >= 0
        out[sub[ok]] = points[sub[ok], 2] - gz[j[ok]]
    return out


def nearest_cell_centre(grid: VoxelGrid, points: np.ndarray, cell: float, bound: float) -> np.ndarray:
    """Index of the occupied cell of the flat ``grid`` whose centre lies nearest each point in
    x-y, -1 where none is closer than ``bound`` (m): the query of a kd-tree on the cell centres
    with ``distance_upper_bound``, done as a grid search. The points are grouped by their own
    cell, and each group tests only the occupied cells of the window around it, so points deep
    inside a cell-less area (under a large roof) cost one lookup. Of equidistant cells the
    lowest index wins (a kd-tree takes the first it visits)."""
    own = VoxelGrid.build(points, cell, flat=True)
    reach = int(np.ceil(bound / cell)) + 1
    start, cand, low = _window_cells(grid.plane, grid.probe_table, grid.coords, own.coords, reach, cell, bound)
    return _nearest_in_lists(points, own.voxel, start, cand, low, grid.coords, cell, bound)


@njit(cache=True, nogil=True)
def _window_cells(plane, table, coords, query, reach, cell, bound):
    """CSR lists of the occupied cells within ``reach`` cells (x and y) of each query cell
    whose centre can lie closer than ``bound`` to a point of the query cell, in increasing
    order of that lower bound (squared, ``low``; the cell taken a hair larger against rounding
    in the cell index of a point)."""
    nq = query.shape[0]
    start = np.zeros(nq + 1, np.int64)
    out = np.empty(64, np.int64)
    low = np.empty(64)
    m = 0
    b2 = bound * bound
    pad = 1e-6 * cell
    for q in range(nq):
        x0, y0 = query[q, 0] * cell - pad, query[q, 1] * cell - pad
        x1, y1 = (query[q, 0] + 1) * cell + pad, (query[q, 1] + 1) * cell + pad
        first = m
        for dx in range(-reach, reach + 1):
            for dy in range(-reach, reach + 1):
                u = find_cell(plane, table, coords, query[q, 0] + dx, query[q, 1] + dy)
                if u < 0:
                    continue
                cx, cy = (coords[u, 0] + 0.5) * cell, (coords[u, 1] + 0.5) * cell
                ex = x0 - cx if cx < x0 else (cx - x1 if cx > x1 else 0.0)
                ey = y0 - cy if cy < y0 else (cy - y1 if cy > y1 else 0.0)
                lb = ex * ex + ey * ey
                if lb >= b2:
                    continue
                if m == out.shape[0]:
                    grown = np.empty(2 * m, np.int64)
                    grown[:m] = out
                    out = grown
                    grown_low = np.empty(2 * m)
                    grown_low[:m] = low
                    low = grown_low
                k = m  # insertion by lower bound
                while k > first and low[k - 1] > lb:
                    out[k], low[k] = out[k - 1], low[k - 1]
                    k -= 1
                out[k], low[k] = u, lb
                m += 1
        start[q + 1] = m
    return start, out[:m].copy(), low[:m].copy()


@njit(cache=True, nogil=True, parallel=True)
def _nearest_in_lists(points, qcell, start, cand, low, coords, cell, bound):
    n = points.shape[0]
    out = np.full(n, -1, np.int64)
    b2 = bound * bound
    for i in prange(n):
        q = qcell[i]
        best = b2
        for k in range(start[q], start[q + 1]):
            if low[k] > best:
                break  # no later cell can be as near (equidistant ones are still tested)
            u = cand[k]
            ex = points[i, 0] - (coords[u, 0] + 0.5) * cell
            ey = points[i, 1] - (coords[u, 1] + 0.5) * cell
            d2 = ex * ex + ey * ey
            if d2 < best or (d2 == best and out[i] >= 0 and u < out[i]):
                best = d2
                out[i] = u
    return out


def adjacent_small_segments(
    points: np.ndarray, segment: np.ndarray, chosen: np.ndarray, max_points: int, voxel: float = 0.33
) -> np.ndarray:
    """Points of segments smaller than ``max_points`` that touch (share or neighbour a voxel
    with) the ``chosen`` points; used by Sec. 4.3 and 4.4 ("as well as small directly adjacent
    segments")."""
    seg, ns = compact(segment)
    if not chosen.any():
        return np.zeros(len(points), dtype=bool)
    grid = VoxelGrid.build(points, voxel)
    hot = grid.neighbourhood_sum(np.bincount(grid.voxel, weights=chosen, minlength=grid.n_voxels)) > 0
    size = np.bincount(seg, minlength=ns)
    touching = np.bincount(seg, weights=hot[grid.voxel] & ~chosen, minlength=ns) > 0
    return ((size < max_points) & touching)[seg] & ~chosen


def _vehicle_like(
    points: np.ndarray,
    group: np.ndarray,
    hag: np.ndarray,
    min_points: int,
    length: tuple[float, float],
    max_width: float,
    height: tuple[float, float],
    max_ground_gap: float,
    solid: np.ndarray,
    verticality: np.ndarray | None = None,
    max_verticality: float = 1.0,
    foliage: np.ndarray | None = None,
) -> np.ndarray:
    """Per group: dimensions in vehicle ranges (length along the principal horizontal axis,
    width across it, height) and bottom at most ``max_ground_gap`` above the nearby ground.
    Extents are taken over the ``solid`` points (in voxels holding several points) so that a
    few stray returns do not widen a car; groups without solid points use all theirs.
    Optionally also: mean ``verticality`` at most ``max_verticality`` and less than half of the
    points ``foliage``."""
    g, ng = compact(group)
    size = np.bincount(g, minlength=ng)
    n = np.maximum(size, 1)
    x, y = points[:, 0], points[:, 1]
    mx, my = np.bincount(g, x, ng) / n, np.bincount(g, y, ng) / n
    dx, dy = x - mx[g], y - my[g]
    sxx, syy, sxy = (np.bincount(g, w, ng) / n for w in (dx * dx, dy * dy, dx * dy))
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    c, s = np.cos(angle)[g], np.sin(angle)[g]
    uvz = np.column_stack([dx * c + dy * s, -dx * s + dy * c, points[:, 2]])
    has_solid = np.bincount(g, weights=solid, minlength=ng) > 0
    use = solid | ~has_solid[g]
    ulo, uhi = segment_bounds(g[use], uvz[use], ng)
    along, across, tall = (uhi - ulo).T
    bottom = np.full(ng, np.inf)
    ok = np.isfinite(hag)
    np.minimum.at(bottom, g[ok], hag[ok])
    like = (
        (size >= min_points)
        & (along >= length[0]) & (along <= length[1]) & (across <= max_width)
        & (tall >= height[0]) & (tall <= height[1])
        & (bottom <= max_ground_gap)
    )  # fmt: skip
    if verticality is not None:
        like &= np.bincount(g, weights=verticality, minlength=ng) <= max_verticality * size
    if foliage is not None:
        like &= np.bincount(g, weights=foliage, minlength=ng) < 0.5 * size
    return like[g]


def detect_vehicles(
    points: np.ndarray,
    segment: np.ndarray,
    ground: np.ndarray,
    min_points: int = 30,
    length: tuple[float, float] = (1.0, 6.0),
    max_width: float = 2.5,
    height: tuple[float, float] = (0.4, 3.5),
    max_ground_gap: float = 0.6,
    small_segment_points: int = 200,
    group_voxel: float = 0.0,
    foliage: np.ndarray | None = None,
    verticality: np.ndarray | None = None,
    max_verticality: float = 1.0,
    posts: np.ndarray | None = None,
    ground_heights: tuple[VoxelGrid, np.ndarray] | None = None,
) -> np.ndarray:
    """Sec. 4.3: segments whose dimensions lie in vehicle ranges and whose bottom lies at most
    ``max_ground_gap`` above the ground beneath and close to them ("average vertical height
    distance to ground points located beneath and close"), plus small adjacent segments.

    With ``group_voxel > 0`` (beyond the paper, after its Sec. 7 outlook "detect adjacent
    segments, which together form a structure"): the same test also runs on groups of the
    segments that touch (26-connected voxels of that side), so a car split into roof,
    bonnet and sides is found as a whole. Groups whose points are mostly ``foliage`` are left
    out: a bush is car-sized too, but made of tiny segments; so are segments and groups whose
    mean ``verticality`` exceeds ``max_verticality`` (1 = paper): simulated cars average at most
    0.31 (roof, bonnet and glass face up), the facade pieces a street scanner sees low on
    buildings ~0.95. Points marked ``posts`` stay out of the groups (a sign pole beside a car
    would widen it past 2.5 m). ``ground_heights``: ``ground_height_grid(ground, 1.0, 3)`` when
    already made.
    """
    hag = height_above_ground(points, ground, heights=ground_heights)
    grid = VoxelGrid.build(points, group_voxel if group_voxel > 0 else 0.3)  # also the solidity test
    solid = grid.counts[grid.voxel] >= 3
    test = (min_points, length, max_width, height, max_ground_gap, solid, verticality, max_verticality, foliage)
    vehicle = _vehicle_like(points, segment, hag, *test)
    vehicle |= adjacent_small_segments(points, segment, vehicle, small_segment_points)
    if group_voxel > 0:
        if posts is None or not posts.any():
            groups = grid.components()[grid.voxel]
        else:
            free = np.flatnonzero(~posts)
            sub = VoxelGrid.build(np.take(points, free, axis=0), group_voxel)
            groups = np.arange(len(points)) + len(points)  # every post point alone
            groups[free] = sub.components()[sub.voxel]
        vehicle |= _vehicle_like(points, groups, hag, *test)
    return vehicle


@njit(cache=True, nogil=True)
def _post_voxels(coords, filled, table, max_run, min_layers):
    """Sec. 4.4 pillars: filled voxels whose horizontal run of filled voxels (along x and y in
    their layer) is at most ``max_run``; stacks of ≥ ``min_layers`` of them, read bottom to top
    per x-y column, are posts."""
    nv = coords.shape[0]
    slim = np.zeros(nv, np.bool_)
    for v in range(nv):
        if not filled[v]:
            continue
        x, y, z = coords[v, 0], coords[v, 1], coords[v, 2]
        ok = True
        for ax in range(2):
            ex, ey = (1, 0) if ax == 0 else (0, 1)
            run = 1
            for sgn in (-1, 1):
                k = 1
                while True:
                    u = find(table, coords, x + sgn * k * ex, y + sgn * k * ey, z)
                    if u < 0 or not filled[u]:
                        break
                    run += 1
                    k += 1
                    if run > max_run:
                        break
            if run > max_run:
                ok = False
        slim[v] = ok
    post = np.zeros(nv, np.bool_)
    for v in range(nv):
        if not slim[v]:
            continue
        below = find(table, coords, coords[v, 0], coords[v, 1], coords[v, 2] - 1)
        if below >= 0 and slim[below]:
            continue  # not the bottom of a stack
        top = v
        n = 1
        while True:
            u = find(table, coords, coords[top, 0], coords[top, 1], coords[top, 2] + 1)
            if u < 0 or not slim[u]:
                break
            top = u
            n += 1
        if n >= min_layers:
            w = v
            for _ in range(n):
                post[w] = True
                w = find(table, coords, coords[w, 0], coords[w, 1], coords[w, 2] + 1)
    return post


def detect_posts(
    points: np.ndarray,
    segment: np.ndarray,
    voxel: float = 0.25,
    min_voxel_points: int = 3,
    max_extent: float = 1.0,
    min_height: float = 1.5,
    small_segment_points: int = 200,
) -> np.ndarray:
    """Sec. 4.4: voxel pillars at least ``min_height`` tall whose filled voxels reach at most
    ``max_extent`` horizontally, plus small adjacent segments."""
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    grid = VoxelGrid.build(points, voxel)
    max_run = max(int(np.floor(max_extent / voxel + 1e-9)), 1)
    min_layers = int(np.ceil(min_height / voxel - 1e-9))
    # the pillar search sees filled voxels only (an empty one ends a run or a stack as a
    # missing one does): a table of those alone, a fraction of the grid's, stays in cache
    filled = np.flatnonzero(grid.counts >= min_voxel_points)
    coords = grid.coords[filled]
    table = _rehash32(coords, len(coords), _table_size(len(coords)))
    post_voxel = np.zeros(grid.n_voxels, bool)
    post_voxel[filled] = _post_voxels(coords, np.ones(len(coords), bool), table, max_run, min_layers)
    post = post_voxel[grid.voxel]
    return post | adjacent_small_segments(points, segment, post, small_segment_points)


def under_crown(
    points: np.ndarray, crown: np.ndarray, cell: float = 1.0, reach: int = 1, above: float = 0.0
) -> np.ndarray:
    """Points whose x-y cell (or a neighbour within ``reach`` cells) holds ``crown`` points
    more than ``above`` (m) higher than the point: a stem under its crown rather than a lamp
    post or a sign; a wall under its roof."""
    if len(points) == 0 or not crown.any():
        return np.zeros(len(points), dtype=bool)
    grid = VoxelGrid.build(points, cell, flat=True)
    top = _cell_top(grid.voxel, crown, points, grid.n_voxels)
    best = _planar_max(grid.plane, grid.probe_table, grid.coords, top, reach)
    return best[grid.voxel] > points[:, 2] + above


@njit(cache=True, nogil=True)
def _cell_top(voxel, mask, points, n_voxels):
    """Highest z of the ``mask`` points per voxel (-inf where none): ``np.maximum.at`` in one pass."""
    top = np.full(n_voxels, -np.inf)
    for i in range(voxel.shape[0]):
        if mask[i] and points[i, 2] > top[voxel[i]]:
            top[voxel[i]] = points[i, 2]
    return top


@njit(cache=True, nogil=True, parallel=True)
def _planar_max(plane, table, coords, values, radius):
    out = np.full(values.shape[0], -np.inf)
    for v in prange(coords.shape[0]):
        for dx in range(-radius, radius + 1):
            for dy in range(-radius, radius + 1):
                u = find_cell(plane, table, coords, coords[v, 0] + dx, coords[v, 1] + dy)
                if u >= 0 and values[u] > out[v]:
                    out[v] = values[u]
    return out


def detect_vegetation(
    points: np.ndarray,
    segment: np.ndarray,
    scene_points: np.ndarray,
    voxel: float = 1.0,
    factor: float = 2.0,
    min_similar: int = 2,
    scene_voxels: int | None = None,
) -> np.ndarray:
    """Sec. 4.5: points in voxels whose segment density (distinct segments of the remaining
    points in the 3x3x3 neighbourhood, Sec. 3.3) is ``factor`` times the average over the
    scene's voxels (``scene_points``: all non-ground points) and with at least ``min_similar``
    neighbouring voxels that high. ``scene_voxels``: :func:`scene_voxel_count` when already
    counted."""
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    density, grid = segment_density(points, segment, voxel)
    n_scene = scene_voxels if scene_voxels is not None else scene_voxel_count(scene_points, voxel)
    n_scene = n_scene or grid.n_voxels
    high = density >= factor * density.sum() / max(n_scene, 1)
    similar = grid.neighbourhood_sum(high.astype(float)) - high
    return (high & (similar >= min_similar))[grid.voxel]


def scene_voxel_count(scene_points: np.ndarray, voxel: float) -> int:
    """The voxels of side ``voxel`` the scene's points occupy (:func:`detect_vegetation`'s
    average is over them); 0 for no points."""
    return len(voxel_counts(scene_points, voxel)) if len(scene_points) else 0
