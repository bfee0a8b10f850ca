"""Ground for spinning multi-beam sensors: a column inclination seed grown through PRC's smooth segments.

PRC's own rule (Lehtola et al. 2019, Sec. II-F: "the largest smooth patch ... is labeled as
ground") was made for a profiler's block, where the road is one long patch. On a spinning
sensor's sweep a curb, a parked car or the crease at a wall's foot splits the road or joins it
to a facade, so the largest patch flips between ground and building from one sweep to the
next. This module replaces that last step of Sec. II-F for spinning sensors; every other step
of Algorithm 1 is unchanged, and ``PRCConfig(ground="largest_smooth")`` (the ``urban`` and
``forest`` presets) keeps the paper's rule.

Steps (each can be switched off and is measured in the README section of the report):

0. **Ground plane under the sensor** (:func:`ground_plane`): the lowest third of the beams
   mostly hits the ground around the vehicle; the lowest well-filled height bin (0.1 m bins, at
   least 30 % of the fullest: ground is the lowest surface, a roof under the sensor is not)
   seeds a least-squares plane through the points within 0.3 m of it. The plane levels the sweep when
   the sensor is tilted (its tilt is reported), and gives the height ``z_ref`` where ground
   starts. Its assumption (ground visible below the sensor) is checked: too few points near the
   plane, or a plane tilted more than 30 degrees, raise :class:`GroundModelError` rather than
   label a wall as ground.
1. **Column inclination seed** (:func:`column_seed`), following the range-image ground
   removal of Bogoslavskyi & Stachniss ("Efficient online segmentation for sparse 3D laser
   scans", PFG 2017, Sec. 3.1), which tests the inclination between the returns of
   consecutive beams in one column. Here each column is walked from the lowest beam up; the
   first return within ``ground_start`` of ``z_ref`` starts the ground, and each further return
   is ground when its height differs from the *last ground return* of the column by at most
   ``tan(ground_slope_deg) * d + ground_step`` over the horizontal distance ``d`` between
   them. Comparing with the last ground return rather than the previous return carries the
   ground past a car or a pole in the column (the returns behind it at road height continue
   it) and over a curb once the horizontal distance has grown.
2. **Local ground height model** (:func:`cell_heights`): the seed's mean height in polar cells
   (``ground_cell_deg`` of azimuth by ``ground_cell_m`` of horizontal range); seed returns more
   than ``ground_tau`` above or below their cell's height are dropped (low bushes, car sills).
3. **PRC segments**: every smooth PRC segment (``H_b \\ V_b``, Sec. II-E) of which at least
   ``ground_segment_share`` is seed contributes its returns within ``ground_tau`` of the local
   ground height: a sidewalk behind a curb, road beyond a gap in the seed.
4. **Temporal consistency** (:class:`GroundState`): the previous sweep's plane replaces a plane
   that cannot be fitted (ground hidden by a truck), and ``z_ref`` is smoothed over sweeps.

All of it works on the sensor-frame coordinates of the slots, with the beams ordered by
elevation from the sensor model (or measured from the coordinates), so it holds for any
number of beams, any column count and either image orientation.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from numba import njit

log = logging.getLogger("prc_slam.prc.ground")


class GroundModelError(ValueError):
    """The sweep does not show the ground below the sensor that the column ground assumes."""


@dataclass
class GroundState:
    """What the column ground carries from one sweep to the next (step 4).

    Attributes
    ----------
    plane : ndarray (4,) or None
        Unit normal (z up) and offset ``n . p + d = 0`` of the last sweep's ground plane.
    z_ref : float or None
        Smoothed height of the ground below the sensor in the levelled frame.
    sweeps, reused : int
        Sweeps seen, and sweeps that reused the previous plane.
    """

    plane: np.ndarray | None = None
    z_ref: float | None = None
    sweeps: int = 0
    reused: int = 0
    smoothing: float = 0.5


@dataclass
class GroundResult:
    """Column ground of one sweep: the mask and what each step contributed."""

    ground: np.ndarray
    seed: np.ndarray
    plane: np.ndarray
    tilt_deg: float
    z_ref: float
    counts: dict[str, int] = field(default_factory=dict)


def beam_order(xyz: np.ndarray, valid: np.ndarray, altitude: np.ndarray | None = None) -> np.ndarray:
    """Rows ordered from the lowest beam to the highest.

    Uses the sensor's beam elevations when given; otherwise the median elevation of each row's
    returns (rows without returns go last).
    """
    if altitude is not None and len(altitude) == valid.shape[0] and np.isfinite(altitude).all():
        return np.argsort(np.asarray(altitude), kind="stable").astype(np.int64)
    rho = np.hypot(xyz[..., 0], xyz[..., 1])
    elev = np.where(valid, np.arctan2(xyz[..., 2], np.maximum(rho, 1e-9)), np.nan)
    with np.errstate(all="ignore"):
        med = np.nanmedian(np.where(valid.any(axis=1)[:, None], elev, 0.0), axis=1)
    med[~valid.any(axis=1)] = np.inf
    return np.argsort(med, kind="stable").astype(np.int64)


def ground_plane(
    xyz: np.ndarray, valid: np.ndarray, order: np.ndarray, max_tilt_deg: float = 30.0
) -> tuple[np.ndarray, int]:
    """Step 0: plane ``n . p + d = 0`` (``n`` unit, ``n_z > 0``) of the ground below the sensor.

    Returns
    -------
    plane : ndarray (4,)
    support : int
        Returns within 0.3 m of the plane used for the fit.

    Raises
    ------
    GroundModelError
        Fewer than 30 supporting returns, or the plane tilted more than ``max_tilt_deg``.
    """
    low = np.ascontiguousarray(order[: max(1, len(order) // 3)])
    pts = _below_sensor(xyz, valid, low, max(1, len(low) * valid.shape[1] // 8000))
    if len(pts) < 30:
        raise GroundModelError(f"only {len(pts)} returns below the sensor in the lowest third of the beams")
    z = pts[:, 2]
    # ground is the lowest surface: the lowest height bin holding at least 30 % of the fullest
    # bin's returns (not the fullest itself, which may be a vehicle's roof under a roof-mounted
    # sensor), then the fullest bin within 0.3 m above it
    hist = np.bincount(((z - z.min()) / 0.1).astype(np.int64))
    first = int(np.argmax(hist >= 0.3 * hist.max()))
    i = first + int(np.argmax(hist[first : first + 4]))
    z0 = float(z.min()) + 0.1 * (i + 0.5)
    plane = np.array([0.0, 0.0, 1.0, -z0])
    for _ in range(2):
        ata, atb, used = _plane_normal_equations(pts, plane, 0.3)
        if used < 30:
            raise GroundModelError(f"only {used} returns near a ground plane below the sensor")
        try:  # z = c0 x + c1 y + c2 by the normal equations
            coef = np.linalg.solve(ata, atb)
        except np.linalg.LinAlgError as exc:
            raise GroundModelError("the returns below the sensor do not span a plane") from exc
        n = np.array([-coef[0], -coef[1], 1.0])
        norm = np.linalg.norm(n)
        plane = np.array([*(n / norm), -coef[2] / norm])
    near = int(_plane_normal_equations(pts, plane, 0.3)[2])
    tilt = float(np.degrees(np.arccos(np.clip(plane[2], -1.0, 1.0))))
    if tilt > max_tilt_deg:
        raise GroundModelError(f"ground plane below the sensor tilted {tilt:.0f} deg (> {max_tilt_deg:.0f})")
    return plane, near


@njit(cache=True, nogil=True)
def _below_sensor(xyz, valid, rows, stride):
    """Returns of ``rows`` below the sensor (z < 0) in every ``stride``-th column."""
    C = valid.shape[1]
    out = np.empty((len(rows) * (C // stride + 1), 3), np.float64)
    k = 0
    for r in rows:
        for c in range(0, C, stride):
            if valid[r, c] and xyz[r, c, 2] < 0.0:
                for a in range(3):
                    out[k, a] = xyz[r, c, a]
                k += 1
    return out[:k]


@njit(cache=True, nogil=True)
def _plane_normal_equations(pts, plane, tol):
    """Normal equations of ``z = c0 x + c1 y + c2`` over the points within ``tol`` of ``plane``."""
    ata = np.zeros((3, 3))
    atb = np.zeros(3)
    used = 0
    for i in range(pts.shape[0]):
        x, y, z = pts[i, 0], pts[i, 1], pts[i, 2]
        if abs(plane[0] * x + plane[1] * y + plane[2] * z + plane[3]) >= tol:
            continue
        used += 1
        v = (x, y, 1.0)
        for a in range(3):
            atb[a] += v[a] * z
            for b in range(3):
                ata[a, b] += v[a] * v[b]
    return ata, atb, used


@njit(cache=True, nogil=True)
def levelled_rho_z(xyz, valid, rot):
    """Horizontal range and height of every slot after the rotation ``rot`` (levelling)."""
    R, C = valid.shape
    rho = np.zeros((R, C), np.float32)
    z = np.zeros((R, C), np.float32)
    for r in range(R):
        for c in range(C):
            if not valid[r, c]:
                continue
            x0 = xyz[r, c, 0]
            y0 = xyz[r, c, 1]
            z0 = xyz[r, c, 2]
            x = rot[0, 0] * x0 + rot[0, 1] * y0 + rot[0, 2] * z0
            y = rot[1, 0] * x0 + rot[1, 1] * y0 + rot[1, 2] * z0
            z[r, c] = rot[2, 0] * x0 + rot[2, 1] * y0 + rot[2, 2] * z0
            rho[r, c] = np.sqrt(x * x + y * y)
    return rho, z


def levelling_rotation(normal: np.ndarray) -> np.ndarray:
    """Rotation taking the unit ``normal`` to +z (Rodrigues; identity when already level)."""
    n = np.asarray(normal, dtype=np.float64)
    v = np.cross(n, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(v), float(n[2])
    if s < 1e-9:
        return np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    return np.eye(3) + s * k + (1 - c) * (k @ k)


@njit(cache=True, nogil=True)
def column_seed(rho, z, valid, order, z_ref, start, tan_slope, step):
    """Step 1: walk every column from the lowest beam up (see the module docstring).

    Parameters
    ----------
    rho, z : float32 (rows, cols)
        Horizontal range and height of the slots in the levelled frame.
    valid : bool (rows, cols)
    order : int64 (rows,)
        Rows from the lowest beam to the highest.
    z_ref, start, tan_slope, step : float
        Ground height below the sensor, ``ground_start``, ``tan(ground_slope_deg)``,
        ``ground_step``.

    Returns
    -------
    bool (rows, cols)
    """
    R, C = valid.shape
    seed = np.zeros((R, C), np.bool_)
    for c in range(C):
        have = False
        rho_g = 0.0
        z_g = 0.0
        for k in range(R):
            r = order[k]
            if not valid[r, c]:
                continue
            if not have:
                if abs(z[r, c] - z_ref) < start:
                    have = True
                    rho_g = rho[r, c]
                    z_g = z[r, c]
                    seed[r, c] = True
                continue
            d = rho[r, c] - rho_g
            if d > 0.0 and abs(z[r, c] - z_g) <= tan_slope * d + step:
                seed[r, c] = True
                rho_g = rho[r, c]
                z_g = z[r, c]
    return seed


@njit(cache=True, nogil=True)
def cell_heights(rho, z, valid, seed, cell_cols, cell_m, n_bins):
    """Step 2: mean seed height per polar cell (``cell_cols`` columns by ``cell_m`` of horizontal
    range; cell of slot ``(r, c)``: :func:`_cell`).

    Returns
    -------
    height : float64 (n_cells,)
        Mean seed height (NaN for cells with fewer than 3 seed returns).
    """
    R, C = valid.shape
    n_sec = (C + cell_cols - 1) // cell_cols
    total = np.zeros(n_sec * n_bins)
    count = np.zeros(n_sec * n_bins)
    for r in range(R):
        for c in range(C):
            if seed[r, c]:
                k = _cell(rho[r, c], c, cell_cols, cell_m, n_bins)
                total[k] += z[r, c]
                count[k] += 1.0
    height = np.full(n_sec * n_bins, np.nan)
    for k in range(n_sec * n_bins):
        if count[k] >= 3.0:
            height[k] = total[k] / count[k]
    return height


@njit(cache=True, nogil=True, inline="always")
def _cell(rho, c, cell_cols, cell_m, n_bins):
    return (c // cell_cols) * n_bins + min(int(rho / cell_m), n_bins - 1)


@njit(cache=True, nogil=True)
def _ground_segments(segments, smooth, seed, share):
    """Step 3: which smooth segments (ids of ``segments``) are at least ``share`` seed."""
    R, C = segments.shape
    n_ids = 1
    for r in range(R):
        for c in range(C):
            n_ids = max(n_ids, segments[r, c] + 1)
    total = np.zeros(n_ids, np.int64)
    hits = np.zeros(n_ids, np.int64)
    for r in range(R):
        for c in range(C):
            if smooth[r, c]:
                total[segments[r, c]] += 1
                hits[segments[r, c]] += seed[r, c]
    ok = np.zeros(n_ids, np.bool_)
    for i in range(1, n_ids):
        ok[i] = total[i] > 0 and hits[i] >= share * total[i]
    return ok


@njit(cache=True, nogil=True)
def _grow(
    rho, z, valid, seed, height, cell_cols, cell_m, n_bins, tau, segments, smooth, seg_ok, use_cells, use_segments
):
    """Steps 2 and 3 per slot: seeds consistent with their cell, plus smooth returns of
    ground-dominated segments within ``tau`` of their cell's height."""
    R, C = valid.shape
    out = np.zeros((R, C), np.bool_)
    for r in range(R):
        for c in range(C):
            if not valid[r, c]:
                continue
            near = True
            has = False
            if use_cells:
                h = height[_cell(rho[r, c], c, cell_cols, cell_m, n_bins)]
                has = not np.isnan(h)
                near = has and abs(z[r, c] - h) < tau
            if seed[r, c]:
                out[r, c] = near or not has
            elif use_segments and has and near and smooth[r, c] and seg_ok[segments[r, c]]:
                out[r, c] = True
    return out


def column_ground(
    xyz: np.ndarray,
    valid: np.ndarray,
    config: object,
    *,
    altitude: np.ndarray | None = None,
    segments: np.ndarray | None = None,
    smooth: np.ndarray | None = None,
    state: GroundState | None = None,
    steps: tuple[str, ...] = ("seed", "cells", "segments", "temporal"),
) -> GroundResult:
    """Ground mask of one sweep (module docstring, steps 0-4).

    Parameters
    ----------
    xyz : float (rows, cols, 3)
        Sensor-frame coordinates of the slots (z roughly up).
    valid : bool (rows, cols)
        Slots with a return.
    config : PRCConfig
        ``ground_*`` parameters.
    altitude : float (rows,), optional
        Beam elevations (rad); otherwise measured from ``xyz``.
    segments, smooth : arrays (rows, cols), optional
        PRC's ``R_b`` and smooth mask (needed for the ``segments`` step).
    state : GroundState, optional
        Carried between sweeps of one recording (step 4); updated in place.
    steps : tuple of str
        Steps to run (``seed`` is always run); for measuring each step's share.

    Raises
    ------
    GroundModelError
        No ground below the sensor in this sweep and no previous sweep to fall back on.
    """
    xyz = np.asarray(xyz, dtype=np.float32)
    valid = np.asarray(valid, dtype=bool)
    order = beam_order(xyz, valid, altitude)
    temporal = state is not None and "temporal" in steps
    try:
        plane, _support = ground_plane(xyz, valid, order)
    except GroundModelError as exc:
        if not temporal or state.plane is None:
            raise
        log.warning("column ground: %s; reusing the previous sweep's ground plane", exc)
        plane = state.plane
        state.reused += 1
    tilt = float(np.degrees(np.arccos(np.clip(plane[2], -1.0, 1.0))))
    rho, z = levelled_rho_z(xyz, valid, levelling_rotation(plane[:3]))
    z_ref = float(-plane[3])
    if temporal:
        if state.z_ref is not None:
            z_ref = state.smoothing * state.z_ref + (1.0 - state.smoothing) * z_ref
        state.plane, state.z_ref = plane, z_ref
        state.sweeps += 1
    seed = column_seed(
        rho,
        z,
        valid,
        order,
        z_ref,
        float(config.ground_start),
        float(np.tan(np.radians(config.ground_slope_deg))),
        float(config.ground_step),
    )
    counts = {"seed": int(seed.sum())}
    use_cells = "cells" in steps
    use_segments = "segments" in steps and segments is not None and smooth is not None
    if not (use_cells or use_segments):
        return GroundResult(seed, seed, plane, tilt, z_ref, counts)
    cols = valid.shape[1]
    cell_cols = max(1, round(cols * config.ground_cell_deg / 360.0))
    n_bins = int(np.ceil(200.0 / config.ground_cell_m))
    cell_m = float(config.ground_cell_m)
    height = cell_heights(rho, z, valid, seed, cell_cols, cell_m, n_bins)
    if use_segments:
        seg = np.ascontiguousarray(segments, dtype=np.int32)
        smooth_arr = np.ascontiguousarray(smooth, dtype=bool)
        seg_ok = _ground_segments(seg, smooth_arr, seed, float(config.ground_segment_share))
    else:
        seg = np.zeros(valid.shape, np.int32)
        seg_ok = np.zeros(1, dtype=bool)
        smooth_arr = np.zeros(valid.shape, dtype=bool)
    ground = _grow(
        rho,
        z,
        valid,
        seed,
        height,
        cell_cols,
        cell_m,
        n_bins,
        float(config.ground_tau),
        seg,
        smooth_arr,
        seg_ok,
        use_cells,
        use_segments,
    )
    counts["dropped_by_cells"] = int((seed & ~ground).sum())
    counts["added_by_segments"] = int((ground & ~seed).sum())
    return GroundResult(ground, seed, plane, tilt, z_ref, counts)
