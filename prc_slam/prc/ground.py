"""Ground for spinning multi-beam sensors: a column inclination seed grown through PRC's smooth segments.

PRC's own rule (Lehtola et al. 2019, Sec. II-F: "the largest smooth patch ... is labeled as
ground") was made for a profiler's block, where the road is one long patch. On a spinning
sensor's sweep a curb, a parked car or the crease at a wall's foot splits the road or joins it
to a facade, so the largest patch flips between ground and building from one sweep to the
next (and forest mode's eq. (12), a profiler block's column smoothness, finds 0.4-0.9 of a simulated
forest's ground on spinning sensors). This module replaces that last step of Sec. II-F for
spinning sensors in either mode; every other step
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

#: stands for the ranges where the kernels get coordinates rather than rays (never read)
_NO_RANGES = np.zeros((1, 1), np.float32)
#: stands for the segment id table where segments carry their ids (never read)
_NO_LUT = np.zeros(1, np.int64)


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
    xyz: np.ndarray,
    valid: np.ndarray,
    order: np.ndarray,
    max_tilt_deg: float = 30.0,
    ranges: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Step 0: plane ``n . p + d = 0`` (``n`` unit, ``n_z > 0``) of the ground below the sensor.

    ``xyz`` are the slots' coordinates, or with ``ranges`` their unit rays (float32, the
    coordinates then being ``xyz * ranges``, computed where needed).

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
    scaled = ranges is not None
    rng = ranges if scaled else _NO_RANGES
    pts = _below_sensor(xyz, rng, scaled, valid, low, max(1, len(low) * valid.shape[1] // 8000))
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


@njit(cache=True, nogil=True, inline="always")
def _coord(rays, ranges, scaled, r, c, a):
    """Coordinate ``a`` of slot ``(r, c)``: ``rays * ranges`` in float32 (as
    :meth:`SensorModel.to_xyz` computes it) when ``scaled``, else ``rays`` holds the coordinates."""
    v = rays[r, c, a]
    return v * ranges[r, c] if scaled else v


@njit(cache=True, nogil=True)
def _below_sensor(rays, ranges, scaled, valid, rows, stride):
    """Returns of ``rows`` below the sensor (z < 0) in every ``stride``-th column (coordinates
    from :func:`_coord`)."""
    C = valid.shape[1]
    out = np.empty((len(rows) * (C // stride + 1), 3), np.float64)
    k = 0
    for r in rows:
        for c in range(0, C, stride):
            if valid[r, c] and _coord(rays, ranges, scaled, r, c, 2) < 0.0:
                for a in range(3):
                    out[k, a] = _coord(rays, ranges, scaled, r, c, a)
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
def levelled_seed(rays, ranges, scaled, valid, rot, order, z_ref, start, tan_slope, step):
    """:func:`levelled_rho_z` and :func:`column_seed` in one pass over the rows, lowest beam
    first: each row is levelled (a loop without branches, which vectorises), then every
    column's walk (its last ground return kept per column) takes that row. Same result as the
    two kernels.

    ``rays`` are planar, ``(3, rows, cols)`` (:func:`planar_rays`): the unit rays when
    ``scaled`` (coordinates ``rays * ranges`` in float32, as :meth:`SensorModel.to_xyz`
    computes them), else the coordinates.

    Returns
    -------
    rho, z : float32 (rows, cols)
    seed : bool (rows, cols)
    n_seed : int
    """
    R, C = valid.shape
    rho = np.zeros((R, C), np.float32)
    z = np.zeros((R, C), np.float32)
    seed = np.zeros((R, C), np.bool_)
    have = np.zeros(C, np.bool_)
    rho_g = np.zeros(C, np.float64)
    z_g = np.zeros(C, np.float64)
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    n_seed = 0
    for k in range(R):
        r = order[k]
        vr = valid[r]
        rx = rays[0, r]
        ry = rays[1, r]
        rz = rays[2, r]
        rr = ranges[r] if scaled else ranges[0]
        rho_r = rho[r]
        z_r = z[r]
        for c in range(C):
            x0 = rx[c] * rr[c] if scaled else rx[c]
            y0 = ry[c] * rr[c] if scaled else ry[c]
            z0 = rz[c] * rr[c] if scaled else rz[c]
            x = r00 * x0 + r01 * y0 + r02 * z0
            y = r10 * x0 + r11 * y0 + r12 * z0
            zz = np.float32(r20 * x0 + r21 * y0 + r22 * z0)
            hh = np.float32(np.sqrt(x * x + y * y))
            z_r[c] = zz if vr[c] else np.float32(0.0)
            rho_r[c] = hh if vr[c] else np.float32(0.0)
        seed_r = seed[r]
        for c in range(C):  # column_seed's walk, one step for every column, without branches
            v = vr[c]
            hv = have[c]
            zc = z_r[c]
            rc = rho_r[c]
            first = v & (not hv) & (abs(zc - z_ref) < start)
            d = rc - rho_g[c]
            more = v & hv & (d > 0.0) & (abs(zc - z_g[c]) <= tan_slope * d + step)
            sd = first | more
            seed_r[c] = sd
            have[c] = hv | first
            rho_g[c] = rc if sd else rho_g[c]
            z_g[c] = zc if sd else z_g[c]
            n_seed += sd
    return rho, z, seed, n_seed


_planar: list[tuple[np.ndarray, np.ndarray]] = []


def planar_rays(xyz: np.ndarray, cache: bool = False) -> np.ndarray:
    """``(rows, cols, 3)`` float32 coordinates or rays as ``(3, rows, cols)`` (contiguous planes);
    with ``cache``, kept for the last few arrays given (a sensor's unit rays, the same array
    object from sweep to sweep)."""
    if cache:
        for src, out in _planar:
            if src is xyz:
                return out
    out = np.ascontiguousarray(np.moveaxis(np.asarray(xyz, dtype=np.float32), 2, 0))
    if cache:
        _planar.insert(0, (xyz, out))
        del _planar[4:]
    return out


@njit(cache=True, nogil=True)
def cells_and_segments(rho, z, seed, cell_cols, cell_m, n_bins, segments, smooth, share, n_ids, use_segments):
    """:func:`cell_heights` and, with ``use_segments``, :func:`_ground_segments` in one pass
    (``n_ids``: any bound above the largest segment id). Same results as the two kernels."""
    R, C = seed.shape
    n_sec = (C + cell_cols - 1) // cell_cols
    total = np.zeros(n_sec * n_bins)
    count = np.zeros(n_sec * n_bins)
    seg_total = np.zeros(n_ids if use_segments else 1, np.int64)
    seg_hits = np.zeros(n_ids if use_segments else 1, np.int64)
    sec = _sectors(C, cell_cols, n_bins)
    for r in range(R):
        for c in range(C):
            sd = seed[r, c]
            if sd:
                k = sec[c] + min(int(rho[r, c] / cell_m), n_bins - 1)
                total[k] += z[r, c]
                count[k] += 1.0
            if use_segments and smooth[r, c]:
                s = segments[r, c]
                seg_total[s] += 1
                seg_hits[s] += sd
    height = np.full(n_sec * n_bins, np.nan)
    for k in range(n_sec * n_bins):
        if count[k] >= 3.0:
            height[k] = total[k] / count[k]
    ok = np.zeros(len(seg_total), np.bool_)
    for i in range(1, len(seg_total)):
        ok[i] = seg_total[i] > 0 and seg_hits[i] >= share * seg_total[i]
    return height, ok


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


@njit(cache=True, nogil=True)
def segment_shares(segments, smooth, seed, share, n_ids, lut, use_lut):
    """:func:`_ground_segments` with ``n_ids`` (any bound above the largest id) given; with
    ``use_lut`` a slot's segment is ``lut[segments[r, c]]``."""
    R, C = segments.shape
    total = np.zeros(n_ids, np.int64)
    hits = np.zeros(n_ids, np.int64)
    for r in range(R):
        for c in range(C):
            if smooth[r, c]:
                s = lut[segments[r, c]] if use_lut else segments[r, c]
                total[s] += 1
                hits[s] += seed[r, c]
    ok = np.zeros(n_ids, np.bool_)
    for i in range(1, n_ids):
        ok[i] = total[i] > 0 and hits[i] >= share * total[i]
    return ok


@njit(cache=True, nogil=True, inline="always")
def _cell(rho, c, cell_cols, cell_m, n_bins):
    return (c // cell_cols) * n_bins + min(int(rho / cell_m), n_bins - 1)


@njit(cache=True, nogil=True)
def _sectors(C, cell_cols, n_bins):
    """First cell of each column's azimuth sector (:func:`_cell` without its integer division)."""
    sec = np.empty(C, np.int64)
    for c in range(C):
        sec[c] = (c // cell_cols) * n_bins
    return sec


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
    rho,
    z,
    valid,
    seed,
    height,
    cell_cols,
    cell_m,
    n_bins,
    tau,
    segments,
    smooth,
    seg_ok,
    use_cells,
    use_segments,
    lut=_NO_LUT,
    use_lut=False,
):
    """Steps 2 and 3 per slot: seeds consistent with their cell, plus smooth returns of
    ground-dominated segments within ``tau`` of their cell's height. Also returns the number of
    seeds dropped and of returns added. With ``use_lut`` a slot's segment is
    ``lut[segments[r, c]]``."""
    R, C = valid.shape
    out = np.zeros((R, C), np.bool_)
    dropped = 0
    added = 0
    sec = _sectors(C, cell_cols, n_bins)
    for r in range(R):
        for c in range(C):
            if not valid[r, c]:
                continue
            sd = seed[r, c]
            # only seeds and smooth returns of ground-dominated segments can be ground
            if not (
                sd or (use_segments and smooth[r, c] and seg_ok[lut[segments[r, c]] if use_lut else segments[r, c]])
            ):
                continue
            near = True
            has = False
            if use_cells:
                h = height[sec[c] + min(int(rho[r, c] / cell_m), n_bins - 1)]
                has = not np.isnan(h)
                near = has and abs(z[r, c] - h) < tau
            if sd:
                g = near or not has
                out[r, c] = g
                if not g:
                    dropped += 1
            elif has and near:
                out[r, c] = True
                added += 1
    return out, dropped, added


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
    ranges: np.ndarray | None = None,
    n_ids: int | None = None,
) -> GroundResult:
    """Ground mask of one sweep (module docstring, steps 0-4).

    Parameters
    ----------
    xyz : float (rows, cols, 3)
        Sensor-frame coordinates of the slots (z roughly up); with ``ranges``, the slots' unit
        rays (``SensorModel.unit_rays``), the coordinates then being ``xyz * ranges`` (float32,
        as :meth:`SensorModel.to_xyz` gives them; computed where needed, not stored).
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
    ranges : float32 (rows, cols), optional
        The range image, when ``xyz`` holds unit rays.
    n_ids : int, optional
        A bound above the largest id in ``segments`` (else found by a pass over it).

    Raises
    ------
    GroundModelError
        No ground below the sensor in this sweep and no previous sweep to fall back on.
    """
    plane, tilt, z_ref, order = ground_frame(xyz, valid, altitude=altitude, state=state, steps=steps, ranges=ranges)
    return ground_from_frame(
        xyz, valid, config, plane, tilt, z_ref, order, segments=segments, smooth=smooth, steps=steps, ranges=ranges,
        n_ids=n_ids,
    )  # fmt: skip


#: :func:`upside_down` says so when a level surface above the sensor holds this many times the
#: returns of the ground below (KITTI 00 turned over: 3.9-4.0; the shared real sweeps, upright,
#: indoors too: at most 2.0)
UPSIDE_DOWN_RATIO = 3.0


def upside_down(xyz: np.ndarray, valid: np.ndarray, altitude: np.ndarray | None = None) -> str | None:
    """Why a sweep looks turned over (z down: a NED frame, a sensor hung upside down), or None.

    :func:`ground_plane` (the column ground's step 0, which takes the ground below the sensor)
    is run on the sweep and on its mirror (y and z negated: the sweep turned over); when the
    turned-over sweep's ground holds :data:`UPSIDE_DOWN_RATIO` times the returns (and at least
    1,000), the points most likely have z down, and PRC's ground (like the online detectors)
    would be wrong without a word. ``xyz``: slot coordinates ``(rows, cols, 3)``."""
    xyz = np.asarray(xyz, dtype=np.float32)
    alt = None if altitude is None else np.asarray(altitude, dtype=np.float64)

    def support(pts: np.ndarray, a: np.ndarray | None) -> int:
        try:
            return ground_plane(pts, valid, beam_order(pts, valid, a))[1]
        except GroundModelError:
            return 0

    below = support(xyz, alt)
    above = support(xyz * np.float32([1.0, -1.0, -1.0]), None if alt is None else -alt)
    if above < 1000 or above < UPSIDE_DOWN_RATIO * below:
        return None
    return (
        f"the points look upside down: a level surface above the sensor holds {above} returns, the ground "
        f"below {below}; PRC's ground and the online detectors take z up (turn the points over: y and z negated)"
    )


def ground_frame(
    xyz: np.ndarray,
    valid: np.ndarray,
    *,
    altitude: np.ndarray | None = None,
    state: GroundState | None = None,
    steps: tuple[str, ...] = ("seed", "cells", "segments", "temporal"),
    ranges: np.ndarray | None = None,
) -> tuple[np.ndarray, float, float, np.ndarray]:
    """Steps 0 and 4 of :func:`column_ground` (same parameters): the ground plane, its tilt
    (deg), the ground height ``z_ref`` below the sensor and the beam order."""
    scaled = ranges is not None
    xyz = np.asarray(xyz, dtype=np.float32)
    valid = np.asarray(valid, dtype=bool)
    alt_ok = altitude is not None and len(altitude) == valid.shape[0] and bool(np.isfinite(altitude).all())
    if scaled and not alt_ok:  # the elevations are measured from the coordinates
        order = beam_order(xyz * np.asarray(ranges, np.float32)[..., None], valid, altitude)
    else:
        order = beam_order(xyz, valid, altitude)
    temporal = state is not None and "temporal" in steps
    try:
        plane, _support = ground_plane(xyz, valid, order, ranges=ranges)
    except GroundModelError as exc:
        if not temporal or state.plane is None:
            raise
        log.warning("column ground: %s; reusing the previous sweep's ground plane", exc)
        plane = state.plane
        state.reused += 1
    tilt = float(np.degrees(np.arccos(np.clip(plane[2], -1.0, 1.0))))
    z_ref = float(-plane[3])
    if temporal:
        if state.z_ref is not None:
            z_ref = state.smoothing * state.z_ref + (1.0 - state.smoothing) * z_ref
        state.plane, state.z_ref = plane, z_ref
        state.sweeps += 1
    return plane, tilt, z_ref, order


def ground_from_frame(
    xyz: np.ndarray,
    valid: np.ndarray,
    config: object,
    plane: np.ndarray,
    tilt: float,
    z_ref: float,
    order: np.ndarray,
    *,
    segments: np.ndarray | None = None,
    smooth: np.ndarray | None = None,
    steps: tuple[str, ...] = ("seed", "cells", "segments", "temporal"),
    ranges: np.ndarray | None = None,
    n_ids: int | None = None,
    seeded: tuple[np.ndarray, np.ndarray, np.ndarray, int] | None = None,
    height: np.ndarray | None = None,
    seg_lut: np.ndarray | None = None,
) -> GroundResult:
    """Steps 1-3 of :func:`column_ground` given its steps 0 and 4 (:func:`ground_frame`).
    ``seeded``: the result of :func:`seed_in_frame` when already computed; ``height``: the cell
    heights of step 2 (:func:`seed_cell_heights`) when already computed; ``seg_lut``: the
    segment id of each value of ``segments`` (e.g. PRC's block-local ``H_b`` ids to stream ids:
    only the smooth slots' ids are read, which ``H_b`` gives before ``R_b`` is combined)."""
    if seeded is None:
        seeded = seed_in_frame(xyz, valid, config, plane, z_ref, order, ranges=ranges)
    rho, z, seed, n_seed = seeded
    counts = {"seed": int(n_seed)}
    use_cells = "cells" in steps
    use_segments = "segments" in steps and segments is not None and smooth is not None
    if not (use_cells or use_segments):
        return GroundResult(seed, seed, plane, tilt, z_ref, counts)
    valid = np.asarray(valid, dtype=bool)
    cell_cols, cell_m, n_bins = _cell_grid(valid.shape[1], config)
    if use_segments:
        seg = np.ascontiguousarray(segments, dtype=np.int32)
        smooth_arr = np.ascontiguousarray(smooth, dtype=bool)
        if n_ids is None and seg_lut is not None:
            n_ids = max(1, int(np.max(seg_lut, initial=0)) + 1)
        elif n_ids is None:
            n_ids = max(1, int(seg.max()) + 1) if seg.size else 1
    else:
        seg = np.zeros(valid.shape, np.int32)
        smooth_arr = np.zeros(valid.shape, dtype=bool)
        n_ids = 1
    share = float(config.ground_segment_share)
    use_lut = seg_lut is not None and use_segments
    lut = np.ascontiguousarray(seg_lut, dtype=np.int64) if use_lut else _NO_LUT
    if use_lut and height is None:
        height = seed_cell_heights(rho, z, seed, config)
    if height is None:
        height, seg_ok = cells_and_segments(
            rho, z, seed, cell_cols, cell_m, n_bins, seg, smooth_arr, share, int(n_ids), use_segments
        )
    elif use_segments:
        seg_ok = segment_shares(seg, smooth_arr, seed, share, int(n_ids), lut, use_lut)
    else:
        seg_ok = np.zeros(1, dtype=bool)
    ground, dropped, added = _grow(
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
        lut,
        use_lut,
    )
    counts["dropped_by_cells"] = int(dropped)
    counts["added_by_segments"] = int(added)
    return GroundResult(ground, seed, plane, tilt, z_ref, counts)


def _cell_grid(cols: int, config: object) -> tuple[int, float, int]:
    """Columns per cell, cell depth (m) and range bins of the polar cells of step 2."""
    cell_cols = max(1, round(cols * config.ground_cell_deg / 360.0))
    return cell_cols, float(config.ground_cell_m), int(np.ceil(200.0 / config.ground_cell_m))


def seed_cell_heights(rho: np.ndarray, z: np.ndarray, seed: np.ndarray, config: object) -> np.ndarray:
    """Step 2's cell heights from the seed alone (:func:`cell_heights`), which need no PRC
    segments: for :func:`ground_from_frame`'s ``height``."""
    cell_cols, cell_m, n_bins = _cell_grid(seed.shape[1], config)
    return cell_heights(rho, z, seed, seed, cell_cols, cell_m, n_bins)


def seed_in_frame(
    xyz: np.ndarray,
    valid: np.ndarray,
    config: object,
    plane: np.ndarray,
    z_ref: float,
    order: np.ndarray,
    *,
    ranges: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Step 1 of :func:`column_ground` (levelled horizontal range and height of every slot,
    the column seed and its size), which needs no PRC segments (:func:`levelled_seed`)."""
    scaled = ranges is not None
    return levelled_seed(
        planar_rays(xyz, cache=scaled),
        np.asarray(ranges, dtype=np.float32) if scaled else _NO_RANGES,
        scaled,
        np.asarray(valid, dtype=bool),
        levelling_rotation(plane[:3]),
        order,
        z_ref,
        float(config.ground_start),
        float(np.tan(np.radians(config.ground_slope_deg))),
        float(config.ground_step),
    )
