"""Fit the polynomial of :func:`prc_slam.online.kernels.arccos` and report its accuracy.

``asin(s) = s + s z g(z)`` with ``z = s^2`` on ``[0, 1/4]``; ``g`` is interpolated at 400
Chebyshev nodes from long-double ``arcsin`` (a series near 0, where ``arcsin(s) - s``
cancels) and written in the power basis of ``z``. Run ``python scripts/fit_arccos.py`` to
print the refitted coefficients and the largest errors of the coefficients in use
(``ARCCOS_G``), in units in the last place, on a million uniform samples of ``[-1, 1]`` and the
ulps next to +-1: of ``arccos`` (radians) against the exact value (long double) and against
numpy's ``arccos``, and of ``arccos_into`` (degrees) against the exact degrees. Measured over 4e7
cosines: 1.13 ulp, 1 ulp and 2.70 ulp. The refit's last digits follow the least-squares (LAPACK) kernels the CPU
selects (here up to 2.4e-3 relative in the highest powers, while the two polynomials agree to
3e-16 relative on ``[0, 1/4]``), so it is not compared digit by digit with ``ARCCOS_G``: the
error above is what matters, and it is what ``tests/online/test_online_equivalence.py`` bounds.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import chebyshev, polynomial

DEGREE = 11


def g(z: np.ndarray) -> np.ndarray:
    """``(asin(sqrt(z)) - sqrt(z)) / z^(3/2)`` in long double."""
    z = np.asarray(z, np.longdouble)
    out = np.empty_like(z)
    small = z < 1e-4
    zs = z[small]  # asin x = x + x^3/6 + 3x^5/40 + 15x^7/336 + 105x^9/3456 + 945x^11/42240 + ...
    c = [np.longdouble(k) for k in ("1", "6", "3", "40", "15", "336", "105", "3456", "945", "42240")]
    out[small] = c[0] / c[1] + zs * (c[2] / c[3] + zs * (c[4] / c[5] + zs * (c[6] / c[7] + zs * c[8] / c[9])))
    x = np.sqrt(z[~small])
    out[~small] = (np.arcsin(x) - x) / (x * z[~small])
    return out


def fit(degree: int = DEGREE) -> np.ndarray:
    """Power-basis coefficients of ``g`` on ``[0, 1/4]``, lowest first."""
    t = np.cos(np.pi * (np.arange(400) + 0.5) / 400)
    z = (t.astype(np.longdouble) + 1) / 8
    cheb = chebyshev.chebfit(t, g(z).astype(np.float64), degree)
    in_z = polynomial.Polynomial(chebyshev.cheb2poly(cheb))(polynomial.Polynomial([-1.0, 8.0]))  # t = 8 z - 1
    return in_z.coef


def ulp_error(ours: np.ndarray, exact: np.ndarray) -> float:
    """The largest ``|ours - exact|`` in units in the last place of the float64 nearest ``exact``."""
    return float(np.max(np.abs((ours.astype(np.longdouble) - exact) / np.spacing(exact.astype(np.float64)))))


def report() -> None:
    """Print the refit and the errors of the coefficients in use."""
    from numba import njit

    from prc_slam.online.kernels import ARCCOS_G, arccos, arccos_into

    refit = fit()
    print("ARCCOS_G (refit) =", tuple(float(c) for c in refit))
    rel = np.abs(refit - np.asarray(ARCCOS_G)) / np.abs(refit)
    print(f"refit vs ARCCOS_G in use: largest relative difference {rel.max():.1e} (follows the LAPACK kernels)")
    tail = np.arange(200_000) * (np.spacing(1.0) / 2)
    c = np.concatenate([np.random.default_rng(0).uniform(-1, 1, 1_000_000), [-1.0, 0.0, 1.0], 1 - tail, tail - 1])
    exact = np.arccos(c.astype(np.longdouble))
    rad = njit(lambda c: np.array([arccos(x) for x in c]))(c)
    deg = c.copy()
    arccos_into(deg, len(deg))
    print(f"arccos, radians: largest error {ulp_error(rad, exact):.2f} ulp of the exact value (long double)")
    numpy = np.arccos(c).astype(np.longdouble)
    print(f"arccos, radians: largest difference {ulp_error(rad, numpy):.2f} ulp of numpy's")
    print(f"arccos_into, degrees: largest error {ulp_error(deg, np.degrees(exact)):.2f} ulp of the exact value")


if __name__ == "__main__":
    report()
