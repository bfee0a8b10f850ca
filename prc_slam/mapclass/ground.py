"""Ground detection of paper 004, Sec. 4.1: grid-minimum terrain and multi-directional slope
scan lines (Meng et al. 2009, with the paper's added diagonals) with a majority vote.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.ndimage import minimum_filter

#: the eight scan-line directions: axis-aligned both ways, then the diagonals both ways
DIRECTIONS = np.array([(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)], dtype=np.int64)


@njit(cache=True, nogil=True)
def _grid_min(points, x0, y0, inv_cell, zmin):
    """Lowest z per cell into ``zmin`` (inf; allocated by numpy: huge pages)."""
    for i in range(points.shape[0]):
        ix = int((points[i, 0] - x0) * inv_cell)
        iy = int((points[i, 1] - y0) * inv_cell)
        if points[i, 2] < zmin[ix, iy]:
            zmin[ix, iy] = points[i, 2]


@njit(cache=True, nogil=True)
def _min_rows(a, w, out):
    """``out`` = minimum over windows of ``w`` (odd) rows centred on each row of ``a`` (nx, ny),
    rows beyond the edges repeating the edge row (``scipy.ndimage.minimum_filter1d(a, w,
    axis=0, mode="nearest")``): van Herk / Gil-Werman over blocks of ``w`` padded rows, three
    comparisons per element whatever ``w``, whole rows at a time (memory order), two blocks of
    scratch."""
    nx, ny = a.shape
    r = w // 2
    nb = (nx + 2 * r + w - 1) // w  # blocks of padded rows (padded row k is a[clip(k - r)])
    g = np.empty((2, w, ny))  # running minimum from each block's first row (this block, next)
    h = np.empty((w, ny))  # ... and from its last row backwards (this block)

    def prefix(b, dst):
        for k in range(w):
            src = a[min(max(b * w + k - r, 0), nx - 1)]
            if k == 0:
                dst[0] = src
            else:
                for j in range(ny):
                    dst[k, j] = min(dst[k - 1, j], src[j])

    prefix(0, g[0])
    for b in range(nb):
        for k in range(w - 1, -1, -1):
            src = a[min(max(b * w + k - r, 0), nx - 1)]
            if k == w - 1:
                h[k] = src
            else:
                for j in range(ny):
                    h[k, j] = min(h[k + 1, j], src[j])
        cur, nxt = b % 2, (b + 1) % 2
        if b + 1 < nb:
            prefix(b + 1, g[nxt])
        for k in range(w):
            i = b * w + k  # out row i: padded rows i .. i + w - 1
            if i >= nx:
                break
            if k == 0:
                out[i] = g[cur, w - 1]
            else:
                for j in range(ny):
                    out[i, j] = min(h[k, j], g[nxt, k - 1, j])
    return out


@njit(cache=True, nogil=True)
def _min_cols(a, w, out):
    """:func:`_min_rows` along the second axis (``minimum_filter1d(a, w, axis=1,
    mode="nearest")``), one row at a time with row-sized scratch."""
    nx, ny = a.shape
    r = w // 2
    m = ((ny + 2 * r + w - 1) // w) * w
    g = np.empty(m)
    h = np.empty(m)
    for i in range(nx):
        row = a[i]
        for k in range(m):
            v = row[min(max(k - r, 0), ny - 1)]
            g[k] = v if k % w == 0 else min(g[k - 1], v)
        for k in range(m - 1, -1, -1):
            v = row[min(max(k - r, 0), ny - 1)]
            h[k] = v if k % w == w - 1 else min(h[k + 1], v)
        for j in range(ny):
            out[i, j] = min(h[j], g[j + w - 1])
    return out


def minimum_window(a: np.ndarray, w: int) -> np.ndarray:
    """``scipy.ndimage.minimum_filter(a, size=w, mode="nearest")`` of a 2-D float array for odd
    ``w`` (the same values: a minimum does not depend on the order of its terms), by two
    one-pass row filters instead of scipy's (0.14 s on a 4 M-cell terrain grid)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    if w % 2 == 0 or a.ndim != 2 or a.size == 0:
        return minimum_filter(a, size=w, mode="nearest")
    return _min_cols(_min_rows(a, w, np.empty_like(a)), w, np.empty_like(a))


@njit(cache=True, nogil=True)
def _xy_bounds(points):
    """Minimum and maximum of x and y (``points[:, :2].min(axis=0)``, ``.max(axis=0)`` in one
    pass; numpy's column reductions of an (N, 3) array are ~10x slower)."""
    lo = np.array([np.inf, np.inf])
    hi = np.array([-np.inf, -np.inf])
    for i in range(points.shape[0]):
        for j in range(2):
            v = points[i, j]
            if v < lo[j]:
                lo[j] = v
            if v > hi[j]:
                hi[j] = v
    return lo, hi


@njit(cache=True, nogil=True)
def _point_mask(points, x0, y0, inv_cell, zmin, ground_cell, tolerance):
    """Points of ground cells at most ``tolerance[ix, iy]`` above their cell's minimum (and not
    more than that below it: points under a cell's supported minimum, :func:`supported_minimum`)."""
    out = np.empty(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        ix = int((points[i, 0] - x0) * inv_cell)
        iy = int((points[i, 1] - y0) * inv_cell)
        dz = points[i, 2] - zmin[ix, iy]
        out[i] = ground_cell[ix, iy] and -tolerance[ix, iy] <= dz <= tolerance[ix, iy]
    return out


@njit(cache=True, nogil=True)
def _support(points, x0, y0, inv_cell, zmin, band, support, around, count):
    """Per cell: ``support`` = its points within ``band`` above its minimum, ``around`` = the
    points of it and its eight neighbours within ``band`` of that minimum in height, ``count`` =
    all its points."""
    nx, ny = zmin.shape
    for i in range(points.shape[0]):
        ix = int((points[i, 0] - x0) * inv_cell)
        iy = int((points[i, 1] - y0) * inv_cell)
        z = points[i, 2]
        count[ix, iy] += 1
        if z - zmin[ix, iy] <= band:
            support[ix, iy] += 1
        for jx in range(max(ix - 1, 0), min(ix + 2, nx)):
            for jy in range(max(iy - 1, 0), min(iy + 2, ny)):
                if abs(z - zmin[jx, jy]) <= band:
                    around[jx, jy] += 1


@njit(cache=True, nogil=True)
def _cells_of(points, x0, y0, inv_cell, flagged, ny):
    """Indices of the points in ``flagged`` cells and each one's cell (``ix * ny + iy``)."""
    n = 0
    for i in range(points.shape[0]):
        if flagged[int((points[i, 0] - x0) * inv_cell), int((points[i, 1] - y0) * inv_cell)]:
            n += 1
    idx = np.empty(n, np.int64)
    key = np.empty(n, np.int64)
    n = 0
    for i in range(points.shape[0]):
        ix = int((points[i, 0] - x0) * inv_cell)
        iy = int((points[i, 1] - y0) * inv_cell)
        if flagged[ix, iy]:
            idx[n] = i
            key[n] = ix * ny + iy
            n += 1
    return idx, key


@njit(cache=True, nogil=True)
def _lowest_supported(key, z, band, need, reach_flat, zmin_flat):
    """Over points sorted by (cell, z): each cell's lowest z with ``need - 1`` more points of the
    cell within ``band`` above it and at most ``reach_flat[cell]`` above the cell's lowest
    point, into ``zmin_flat`` (left as it is where none has)."""
    n = len(key)
    start = 0
    while start < n:
        end = start
        while end < n and key[end] == key[start]:
            end += 1
        reach = reach_flat[key[start]]
        for i in range(start, end - need + 1):
            if z[i] - z[start] > reach:
                break
            if z[i + need - 1] - z[i] <= band:
                zmin_flat[key[start]] = z[i]
                break
        start = end


def supported_minimum(
    points: np.ndarray,
    x0: float,
    y0: float,
    cell: float,
    zmin: np.ndarray,
    band: float,
    need: int,
    window: int = 13,
    reach: float = 1.0,
) -> int:
    """Raise each cell's minimum to the lowest point with ``need - 1`` more points of the cell
    within ``band`` above it (in place; returns the number of cells raised or left out).

    Sec. 4.1 takes a cell's lowest point as its terrain height, and every cell within
    ``local_radius`` is then measured against it: one return under the surface (an outlier or
    multipath return close enough under the ground to borrow its density, which the Sec. 3.1
    filter cannot tell from the ground) takes the ground of a 6 x 6 m square with it. A
    simulated mobile map with 5 % outliers per sweep had such a point in 9 % of its ground cells
    and lost 78 % of its ground. A surface is a dense layer; a stray return is alone at its
    height. Sparse ground under trees is alone in its cell too, but has company in the cells
    around (``need`` points of the cell and its eight neighbours within ``band`` of it): such a
    lowest point is passed over only for a dense layer at most ``reach`` above it (the Sec. 3.1
    neighbourhood, ~1 m tall: a return that close under a surface borrows its density), not for
    a crown metres above. Cells in which no point has that company keep their lowest point. A
    cell of fewer than ``need`` points (a stray return or two in a cell the surfaces did not
    reach) takes no part (``inf``) when it lies more than ``band`` below every cell of ``need``
    points or more in the ``window`` (cells) around it, and keeps its lowest point otherwise
    (where the whole neighbourhood is sparse). ``need = 1``: the paper's minimum."""
    if need <= 1:
        return 0
    inv = 1.0 / cell
    support = np.zeros(zmin.shape, np.int64)
    around = np.zeros(zmin.shape, np.int64)
    count = np.zeros(zmin.shape, np.int64)
    _support(points, x0, y0, inv, zmin, band, support, around, count)
    before = zmin.copy()
    flagged = (support < need) & (count >= need)
    if flagged.any():
        idx, key = _cells_of(points, x0, y0, inv, flagged, zmin.shape[1])
        z = points[idx, 2]
        order = np.lexsort((z, key))
        reaches = np.where(around >= need, reach, np.inf).reshape(-1)
        _lowest_supported(key[order], z[order], band, need, reaches, zmin.reshape(-1))
    sparse = (count > 0) & (count < need)
    if sparse.any():
        dense_low = minimum_window(np.where(count >= need, zmin, np.inf), window)
        zmin[sparse & np.isfinite(dense_low) & (zmin < dense_low - band)] = np.inf
    return int((zmin != before).sum())


@njit(cache=True, nogil=True)
def _minmod(a, b):
    """The smaller of two one-sided slopes when they agree in sign, else 0 (NaN: the other)."""
    if np.isnan(a):
        return 0.0 if np.isnan(b) else b
    if np.isnan(b):
        return a
    if a * b <= 0:
        return 0.0
    return a if abs(a) < abs(b) else b


@njit(cache=True, nogil=True)
def slope_tolerance(zmin, ground_cell, cell, tolerance, max_step, terrain_slope, out):
    """``out`` = ``tolerance``, or where more, ``max_step`` plus the rise of the terrain across a
    ground cell, ``(|sx| + |sy|) · cell`` (level ground keeps ``tolerance``), with ``sx``,
    ``sy`` the terrain slopes from the neighbouring ground cells' minima (one-sided
    differences, the smaller where both agree: a plane's slope on a plane, the gentler side at
    a break; at most ``terrain_slope``). On a 30 deg slope the points of one 0.7 m cell span
    0.4-0.6 m: ``tolerance`` alone drops most of them."""
    nx, ny = zmin.shape
    for i in range(nx):
        for j in range(ny):
            if not ground_cell[i, j]:
                out[i, j] = tolerance
                continue
            z = zmin[i, j]
            lo = (z - zmin[i - 1, j]) / cell if i > 0 and ground_cell[i - 1, j] else np.nan
            hi = (zmin[i + 1, j] - z) / cell if i + 1 < nx and ground_cell[i + 1, j] else np.nan
            sx = min(abs(_minmod(lo, hi)), terrain_slope)
            lo = (z - zmin[i, j - 1]) / cell if j > 0 and ground_cell[i, j - 1] else np.nan
            hi = (zmin[i, j + 1] - z) / cell if j + 1 < ny and ground_cell[i, j + 1] else np.nan
            sy = min(abs(_minmod(lo, hi)), terrain_slope)
            out[i, j] = max(tolerance, max_step + (sx + sy) * cell)
    return out


def scan_line_votes(
    zmin: np.ndarray,
    zlocal: np.ndarray,
    cell: float,
    max_slope: float,
    max_step: float,
    max_above_local: float,
    terrain_slope: float = 0.0,
) -> np.ndarray:
    """Ground votes per cell from the eight scan-line directions.

    Along a scan line a non-empty cell is ground when (a) it is at most ``max_above_local``
    above the minimum of its neighbourhood (``zlocal``) and (b) it rises from the last ground
    cell of the line by at most ``max_slope · distance + max_step`` (descents always pass); the
    first non-empty cell of a line needs (a) only. Empty cells carry the last ground height on.
    With ``terrain_slope`` > 0, (b) also passes a cell that continues the line's ground without
    a break: the last non-empty cell was ground, at most two steps back, and the rise from it
    is at most ``terrain_slope · distance + max_step`` (a hillside climbed cell by cell, not a
    wall, which rises metres within a cell; the paper's ``max_slope`` still bounds the rise
    across a break, where the distance since the last ground would otherwise let any height
    pass).

    Returns
    -------
    votes : int64 (nx, ny)
        Directions that saw the cell as ground (0..8).
    """
    votes = np.zeros(zmin.shape, np.int64)
    _add_votes(zmin, zlocal, cell, max_slope, max_step, max_above_local, terrain_slope, votes)
    return votes


@njit(cache=True, nogil=True)
def _add_votes(zmin, zlocal, cell, max_slope, max_step, max_above_local, terrain_slope, votes):
    """:func:`scan_line_votes` into ``votes`` (zeros)."""
    nx, ny = zmin.shape
    # all lines of a direction are swept at once, row by row of the grid (each line meets a
    # row once, in its own order), with the state of every line (last ground height, distance
    # since) kept per line: the grid is read in memory order, not along the lines
    zg = np.empty(nx + ny + 1)
    dist = np.empty(nx + ny + 1)
    follow = np.zeros(nx + ny + 1, np.bool_)  # the line's last non-empty cell was ground
    for d in range(DIRECTIONS.shape[0]):
        dx, dy = DIRECTIONS[d, 0], DIRECTIONS[d, 1]
        step = cell * np.sqrt(dx * dx + dy * dy)
        reach = 2.5 * step  # "without a break": at most one empty cell between
        zg[:] = np.nan
        dist[:] = 0.0
        follow[:] = False
        for i in range(nx):
            x = i if dx >= 0 else nx - 1 - i
            for j in range(ny):
                y = j if dy >= 0 else ny - 1 - j
                # the line through (x, y): fixed x, fixed y, or a diagonal
                line = x if dx == 0 else (y if dy == 0 else (y - x + nx if dx == dy else y + x))
                dist[line] += step
                z = zmin[x, y]
                if np.isfinite(z):
                    ok = z - zlocal[x, y] <= max_above_local
                    if ok and not np.isnan(zg[line]):
                        rise = z - zg[line]
                        ok = rise <= max_slope * dist[line] + max_step or (
                            follow[line] and dist[line] < reach and rise <= terrain_slope * dist[line] + max_step
                        )
                    if ok:
                        votes[x, y] += 1
                        zg[line] = z
                        dist[line] = 0.0
                    follow[line] = ok and terrain_slope > 0


def opening_window(a: np.ndarray, w: int) -> np.ndarray:
    """Grey-scale opening of ``a`` by a ``w`` x ``w`` flat square (odd ``w``): per cell, the
    highest minimum among the windows that contain it (a minimum over windows, then a maximum
    over the same windows; windows may reach past the grid's edge, where they hold nothing).
    Empty cells (``inf``) take no part. A cell's value is the lowest surface of the
    neighbourhood *on its own side* of a slope or an edge: on any plane, on a rim or at the foot
    of a wall it is the cell itself, on an object narrower than ``w`` cells the ground beside
    it (the filter of Zhang et al. 2003 with one window)."""
    r = w // 2
    low = minimum_window(np.pad(np.asarray(a, np.float64), r, constant_values=np.inf), w)
    low[np.isinf(low)] = -np.inf  # windows without a point: no minimum to offer
    np.negative(low, out=low)
    out = minimum_window(low, w)[r : r + a.shape[0], r : r + a.shape[1]]
    np.negative(out, out=out)
    return out


def terrain_relief(zmin: np.ndarray, cell: float, block: float = 10.0, rank: int = 2) -> float:
    """How far the terrain departs from level: the median slope (rise per metre) between
    neighbouring ``block``-metre blocks of the grid-minimum surface ``zmin`` (cells of ``cell``
    m, ``inf`` where empty), each block at its ``rank``-th lowest cell (from 0: the third, so
    that a stray low return or two left in a block do not set its height; blocks with fewer
    cells are empty). The median over the blocks' pairs is the slope of most of the terrain:
    roofs over whole blocks and walls are the few; 0 when fewer than two neighbouring blocks
    hold points. The paper's window test (a cell at most ``max_above_local`` above the lowest
    cell ``local_radius`` around) holds on level ground only: on a slope of ``s`` the window's
    foot lies ``s * local_radius * sqrt(2)`` lower."""
    k = max(1, round(block / cell))
    nx, ny = (-(-np.array(zmin.shape) // k) * k).tolist()
    padded = np.full((nx, ny), np.inf)
    padded[: zmin.shape[0], : zmin.shape[1]] = zmin
    blocks = padded.reshape(nx // k, k, ny // k, k).transpose(0, 2, 1, 3).reshape(nx // k, ny // k, k * k)
    rank = min(rank, k * k - 1)
    low = np.partition(blocks, rank, axis=-1)[..., rank]
    with np.errstate(invalid="ignore"):  # empty blocks: inf - inf
        rise = np.concatenate([np.abs(np.diff(low, axis=ax)).ravel() for ax in (0, 1)])
    rise = rise[np.isfinite(rise)]
    return float(np.median(rise)) / (k * cell) if len(rise) else 0.0


def detect_ground(
    points: np.ndarray,
    cell: float = 0.5,
    local_radius: float = 3.0,
    max_slope: float = 0.3,
    max_step: float = 0.1,
    max_above_local: float = 0.5,
    tolerance: float = 0.2,
    terrain_relative: bool | str = False,
    terrain_slope: float = 0.84,
    min_relief: float = 0.05,
    min_support: int = 1,
    reach: float = 1.0,
    info: dict | None = None,
) -> np.ndarray:
    """Sec. 4.1: ground mask of ``points``.

    Parameters
    ----------
    points : float (N, 3)
        World coordinates, z up.
    cell : float
        Grid cell (m) of the minimum-z terrain model.
    local_radius : float
        Half-width (m) of the window of the local minimum elevation.
    max_slope, max_step, max_above_local : float
        Scan-line tests (see :func:`scan_line_votes`).
    tolerance : float
        A point of a ground cell is ground when at most this far (m) above the cell minimum.
    terrain_relative : bool or "auto"
        False (the paper's Sec. 4.1): a cell is compared with the minimum of the window
        centred on it. True (terrain): with the lowest surface of its own side of
        the neighbourhood (:func:`opening_window`), so that slopes, rims of terraces and
        quarry walls, and hilltops are not measured against the foot of the slope below them;
        scan lines follow ground that rises without a break up to ``terrain_slope``
        (:func:`scan_line_votes`), and on a slope a ground cell's points may lie the terrain's
        rise across the cell (plus ``max_step``) above its minimum (:func:`slope_tolerance`).
        ``"auto"``: True where the terrain is not level (:func:`terrain_relief` at least
        ``min_relief``), the paper's test on level ground.
    terrain_slope : float
        With ``terrain_relative``: the steepest terrain followed (rise per metre; 0.84 = 40 deg).
    min_relief : float
        ``"auto"``: the median slope (rise per metre) from which the terrain is not level.
    min_support : int
        A cell's terrain height is its lowest point with ``min_support - 1`` more points within
        ``tolerance`` above it (:func:`supported_minimum`; found at most ``reach`` m above a lowest
        point that has company in the cells around); 1: its lowest point (the paper).
    info : dict, optional
        Filled with ``terrain`` (whether the terrain-relative test ran), in ``"auto"``,
        ``relief``, and ``raised_cells`` (cells whose lowest point lacked support).

    Returns
    -------
    bool (N,)
        True where more of the eight scan lines call the point ground than not.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    lo, hi = _xy_bounds(pts)
    nx, ny = (np.floor((hi - lo) / cell).astype(np.int64) + 2).tolist()  # +1 spare for rounding
    zmin = np.full((nx, ny), np.inf)
    _grid_min(pts, lo[0], lo[1], 1.0 / cell, zmin)
    w = 2 * int(np.ceil(local_radius / cell)) + 1
    info = {} if info is None else info
    info["raised_cells"] = supported_minimum(pts, lo[0], lo[1], cell, zmin, tolerance, min_support, w, reach)
    if terrain_relative == "auto":
        info["relief"] = terrain_relief(zmin, cell)
        terrain_relative = info["relief"] >= min_relief
    info["terrain"] = bool(terrain_relative)
    slope = terrain_slope if terrain_relative else 0.0  # 0: the paper's Sec. 4.1
    zlocal = opening_window(zmin, w) if terrain_relative else minimum_window(zmin, w)
    votes = scan_line_votes(zmin, zlocal, cell, max_slope, max_step, max_above_local, slope)
    ground_cell = votes > len(DIRECTIONS) - votes
    if terrain_relative:
        tol = slope_tolerance(zmin, ground_cell, cell, tolerance, max_step, terrain_slope, np.empty_like(zmin))
    else:
        tol = np.full(zmin.shape, tolerance)
    return _point_mask(pts, lo[0], lo[1], 1.0 / cell, zmin, ground_cell, tol)
