"""Fit the polynomial of :func:`prc_slam.online.kernels.arccos` and report its accuracy.

``asin(s) = s + s z g(z)`` with ``z = s^2`` on ``[0, 1/4]``; ``g`` is interpolated at 400
Chebyshev nodes from long-double ``arcsin`` (a series near 0, where ``arcsin(s) - s``
cancels) and written in the power basis of ``z``. Run ``python scripts/fit_arccos.py`` to
print the coefficients (``ARCCOS_G``) and the largest error of ``arccos_into`` (degrees)
against numpy's, in units in the last place, on a million uniform samples of ``[-1, 1]``.
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


if __name__ == "__main__":
    from prc_slam.online.kernels import ARCCOS_G, arccos_into

    print("ARCCOS_G =", tuple(float(c) for c in fit()))
    x = np.random.default_rng(0).uniform(-1, 1, 1_000_000)
    ours = x.copy()
    arccos_into(ours, len(ours))
    ref = np.degrees(np.arccos(x))
    print("largest error (ulp):", float(np.max(np.abs(ours - ref) / np.spacing(ref))))
    print("coefficients in use match the fit:", np.allclose(ARCCOS_G, fit(), rtol=1e-12, atol=0))
