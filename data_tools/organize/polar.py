"""Per-point polar coordinates: the organiser's first pass over a sweep.

Range, azimuth and the tangent of the beam elevation of every point, whether it has a return, and
along the input order the figures that tell the point order (:func:`polar`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: points farther than this (m) are no returns (a placeholder such as 3e38 for "no return", not a
#: measurement: it would otherwise form a ring of its own)
MAX_RANGE = 1e5
TWO_PI = 2.0 * np.pi


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped into (-pi, pi]."""
    return np.angle(np.exp(1j * a))


@njit(cache=True, nogil=True, inline="always")
def fast_atan2(y, x):
    """atan2 by a degree-11 minimax polynomial (|error| < 2e-6 rad, far below a column).

    Inlined into kernels of other modules too (:mod:`~data_tools.organize.beams`), whose numba
    cache does not see a change here: ``make clean-cache`` after editing it."""
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    if mx == 0.0:
        return 0.0
    a = min(ax, ay) / mx
    q = a * a
    r = (((((-0.0117212 * q + 0.05265332) * q - 0.11643287) * q + 0.19354346) * q - 0.33262347) * q + 0.99997726) * a
    if ay > ax:
        r = 1.5707963267948966 - r
    if x < 0.0:
        r = 3.141592653589793 - r
    if y < 0.0:
        r = -r
    return r


@njit(cache=True, nogil=True)
def polar(xyz, offset, ok, rng, az, te, cloud, small=0.7853981633974483):
    """Per point: has a return (finite, not at the origin, nearer than :data:`MAX_RANGE`), range,
    azimuth (rad, (-pi, pi]) and the tangent of the beam
    elevation ``z / (rho - offset)``, ``offset`` being the horizontal distance of the beam
    origins from the sensor axis (Ouster: ``lidar_origin_to_beam_origin``; 0 for decoders
    that give points from one origin). Along the input order also: the share of azimuth
    steps between consecutive returns smaller than ``small`` and the signed sum of those
    steps (revolutions * 2 pi), which tell the point order. Writes into ``ok, rng, az, te``
    (work arrays reused from sweep to sweep: fresh ones cost page faults) and copies the
    points into ``cloud`` (float32, no-return rows zeroed)."""
    n = xyz.shape[0]
    prev = 0.0
    have = False
    steps = 0
    n_small = 0
    total = 0.0
    for i in range(n):
        x = float(xyz[i, 0])
        y = float(xyz[i, 1])
        z = float(xyz[i, 2])
        rho2 = x * x + y * y
        r2 = rho2 + z * z
        good = math.isfinite(r2) and r2 > 0.0 and r2 < MAX_RANGE * MAX_RANGE
        ok[i] = good
        if good:
            cloud[i, 0] = x
            cloud[i, 1] = y
            cloud[i, 2] = z
        else:
            cloud[i, 0] = 0.0
            cloud[i, 1] = 0.0
            cloud[i, 2] = 0.0
            rng[i] = 0.0
            az[i] = 0.0
            te[i] = 0.0
            continue
        rho = math.sqrt(rho2)
        rng[i] = math.sqrt(r2)
        a = fast_atan2(y, x)
        az[i] = a
        h = rho - offset
        te[i] = z / h if h > 1e-6 else (1e6 if z > 0 else -1e6)
        if have:
            d = a - prev
            if d > np.pi:
                d -= 2.0 * np.pi
            elif d <= -np.pi:
                d += 2.0 * np.pi
            steps += 1
            if abs(d) < small:
                n_small += 1
                total += d
        prev = a
        have = True
    return n_small / max(steps, 1), total
