"""The spin-axis search: the axis a multi-beam sensor spun about, from one sweep.

Azimuths and elevations are measured about the sensor's spin axis: found on the first sweep
(:func:`estimate_spin_axis`: the axis about which the elevations bunch at the beams) and used when
it is clearly off the points' ``z`` (a sweep given in a vehicle frame or on a tilted mount's base,
:func:`find_spin_axis`); the points are not moved, the sensor model's rays are turned back into
their frame.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from data_tools.organize.polar import MAX_RANGE
from prc_slam.prc.ground import levelling_rotation

#: :func:`estimate_spin_axis` searches this far (deg) from the points' z axis
SPIN_AXIS_MAX_TILT_DEG = 20.0
#: the points are organised about the spin axis found when it is at least this far from z (deg;
#: KITTI 00's own sweeps give 0.36, level sensors' 0-0.4; 2 deg already put 15 % of a 64-beam
#: sweep's points in another beam's slots) ...
SPIN_AXIS_MIN_TILT_DEG = 1.0
#: ... and its elevation histogram (0.1 deg bins) is this much sharper than about z (sum of squared
#: counts: 1.05 at a 1.2 deg tilt of a KITTI sweep, 1.13 at 3 deg, 1.9 at 15 deg; 1.00-1.03 for the
#: level sensors of the shared data)
SPIN_AXIS_MIN_GAIN = 1.04


@njit(cache=True, nogil=True)
def _axis_sharpness(u, axes, bin_rad, out):
    """For each axis (unit rows of ``axes``): the sharpness of the histogram of ``u . axis`` (the
    sines of the elevations of the unit vectors ``u`` about that axis) in bins of ``bin_rad``,
    smoothed by (1, 2, 1) / 4 so that bin edges do not count, summed squared."""
    inv_bin = 1.0 / bin_rad
    nb = int(2.0 * inv_bin) + 5  # sines in [-1, 1] (rounding may step past): bins 1 .. nb - 2
    h = np.zeros(nb)
    for k in range(axes.shape[0]):
        lo, hi = nb, -1
        for i in range(u.shape[0]):
            s = u[i, 0] * axes[k, 0] + u[i, 1] * axes[k, 1] + u[i, 2] * axes[k, 2]
            b = int((min(max(s, -1.0), 1.0) + 1.0) * inv_bin) + 2
            h[b] += 1.0
            lo = min(lo, b)
            hi = max(hi, b)
        total = 0.0
        for j in range(lo - 1, hi + 2):
            v = 0.25 * h[j - 1] + 0.5 * h[j] + 0.25 * h[j + 1]
            total += v * v
        h[lo : hi + 1] = 0.0
        out[k] = total


def _axes_around(axis: np.ndarray, half_deg: float, step_deg: float) -> np.ndarray:
    """Unit axes on a square grid of ``step_deg`` within ``half_deg`` of ``axis`` (in tangent-plane
    angles; ``axis`` itself at the centre)."""
    t1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(axis, t1)
    k = round(half_deg / step_deg)
    g = np.tan(np.radians(step_deg * np.arange(-k, k + 1)))
    dx, dy = (a.ravel() for a in np.meshgrid(g, g))
    v = axis[None, :] + dx[:, None] * t1[None, :] + dy[:, None] * t2[None, :]
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def estimate_spin_axis(
    xyz: np.ndarray, max_tilt_deg: float = SPIN_AXIS_MAX_TILT_DEG, samples: int = 20000
) -> tuple[np.ndarray, float, float]:
    """The axis a multi-beam sensor spun about, from one sweep given in a frame within
    ``max_tilt_deg`` of it (a vehicle frame, a tilted mount's base).

    Each beam sweeps a cone about the spin axis, so about the right axis the elevations of the
    points bunch at the beams' elevations and the elevation histogram is sharpest (largest sum
    of squared counts, as :func:`~data_tools.organize.beams.estimate_beam_offset` judges an
    offset); about an axis tilted by ``t`` every beam smears over +-``t``. Searched on a grid in
    four steps (1 deg steps over the whole range, ``z`` itself on the grid, on 4,000 points; then
    0.25, 0.05 and 0.01 deg around the best on up to 20,000), the points nearer than 3 m left out
    (beam-origin offsets smear those); not at all when the sweep is sharper about ``z`` than about
    the eight axes 1 deg around it (a level sweep: ``z`` is returned at once). Not a search over
    every direction: a cloud with many points on one plane through the sensor (the scan columns of
    a solid-state sensor such as the AT128) is sharpest about that plane's normal, far from any
    spin axis.

    Returns
    -------
    axis : ndarray (3,)
        Unit spin axis in the points' frame (``z`` when nothing better is found).
    tilt_deg : float
        Its angle from ``z``; ``nan`` when the best axis of the first step lies on the edge of
        the range (the spin axis is likely farther off: nothing is concluded).
    gain : float
        Sharpness about ``axis`` over that about ``z`` (0.1 deg bins; 1 when they are the same).
    """
    z = np.array([0.0, 0.0, 1.0])
    xyz = np.asarray(xyz)
    pick = np.random.default_rng(0).permutation(len(xyz))[: 3 * samples]  # in random order: u[:n] is a random subset
    p = xyz[pick].astype(np.float64)
    r = np.linalg.norm(p, axis=1)
    keep = np.flatnonzero(np.isfinite(r) & (r > 3.0) & (r < MAX_RANGE))[:samples]
    if len(keep) < 500:
        return z, 0.0, 1.0
    u = p[keep] / r[keep, None]
    # the common case first: a level sweep is sharper about z than about the 8 axes 1 deg around
    ring = _axes_around(z, 1.0, 1.0)
    score = np.empty(len(ring))
    _axis_sharpness(u, ring, np.radians(0.1), score)
    if score[4] > score.max(initial=0.0, where=np.arange(len(ring)) != 4):  # (4: z itself)
        return z, 0.0, 1.0
    axis = z
    for k, (half, step, bin_deg, n) in enumerate(
        ((max_tilt_deg, 1.0, 0.2, 4000), (1.5, 0.25, 0.1, 8000), (0.3, 0.05, 0.05, None), (0.06, 0.01, 0.02, None))
    ):
        cand = _axes_around(axis, half, step)
        score = np.empty(len(cand))
        _axis_sharpness(u[:n], cand, np.radians(bin_deg), score)
        i = int(np.argmax(score))
        side = round(np.sqrt(len(cand)))
        if k == 0 and (i // side in (0, side - 1) or i % side in (0, side - 1)):
            return cand[i], float("nan"), 1.0
        axis = cand[i]
    both = np.empty(2)
    _axis_sharpness(u, np.stack([z, axis]), np.radians(0.1), both)
    tilt = float(np.degrees(np.arccos(np.clip(axis[2], -1.0, 1.0))))
    return axis, tilt, float(both[1] / both[0]) if both[0] > 0 else 1.0


def find_spin_axis(xyz: np.ndarray, source: str, warnings: list[str]) -> tuple[bool, np.ndarray | None, float]:
    """Whether this sweep decides the spin axis (False: fewer than 1,000 finite points, the next
    sweep decides), and the rotation from the points' frame into the spin frame with the axis's
    tilt (deg) when the axis is clearly off ``z`` (:data:`SPIN_AXIS_MIN_TILT_DEG`,
    :data:`SPIN_AXIS_MIN_GAIN`; else None, 0). Says in ``warnings`` when it is, or when the search
    ends on the edge of its range."""
    if int(np.isfinite(xyz).all(axis=1).sum()) < 1000:
        return False, None, 0.0
    axis, tilt, gain = estimate_spin_axis(xyz)
    if np.isnan(tilt):
        warnings.append(
            f"{source}: the beams bunch best about an axis {SPIN_AXIS_MAX_TILT_DEG:.0f} deg or more from the "
            "points' z axis (a sensor mounted on its side?): organised about z, which may fail; give the points "
            "in the sensor's frame"
        )
        return True, None, 0.0
    if tilt < SPIN_AXIS_MIN_TILT_DEG or gain < SPIN_AXIS_MIN_GAIN:
        return True, None, 0.0
    ax, ay, az = axis
    warnings.append(
        f"{source}: the sensor spun about ({ax:.3f}, {ay:.3f}, {az:.3f}), {tilt:.1f} deg from the points' z axis "
        "(points in a vehicle or tilted frame?): organised about the spin axis (the points are not moved)"
    )
    return True, levelling_rotation(axis), tilt
