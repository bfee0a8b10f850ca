"""The closed-form 3x3 eigen solver of the map classification's normals
(prc_slam.mapclass.metrics._closed_form3) against LAPACK, and its hand-off to the Jacobi sweeps."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam.mapclass import metrics as M


def _solve(a):
    return M._closed_form3(a[0, 0], a[1, 1], a[2, 2], a[0, 1], a[0, 2], a[1, 2])


def test_hand_computed():
    # diag(1, 2, 3) rotated by 90 degrees about z: eigenvalues 1, 2, 3, smallest along y
    a = np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 3.0]])
    assert not _solve(a)[0]  # diagonal: the Jacobi sweeps answer
    a[0, 1] = a[1, 0] = 1e-3
    ok, w0, w1, w2, n0, n1, n2 = _solve(a)
    w = np.linalg.eigvalsh(a)
    assert ok and np.allclose([w0, w1, w2], w, atol=1e-14)
    assert abs(n1) > 0.999999 and abs(n0) < 1.1e-3 and n2 == 0.0
    # two equal smallest eigenvalues (a line's spread): no unique normal, handed over
    r = np.linalg.qr(np.array([[1.0, 2, 3], [0, 1, 4], [5, 6, 0]]))[0]
    line = r @ np.diag([1.0, 1.0, 9.0]) @ r.T
    assert not _solve(line)[0]


@settings(max_examples=300, deadline=None)
@given(
    flat=st.floats(1e-6, 1.0),
    spread=st.floats(1e-3, 1e3),
    seed=st.integers(0, 2**32 - 1),
)
def test_agrees_with_lapack(flat, spread, seed):
    """Covariances of random patches (a plane of thickness ``flat`` relative to its extent):
    eigenvalues within 1e-12 of the largest, the normal parallel to LAPACK's up to eps |A| / gap."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(0, spread, (50, 3)) * [1.0, rng.uniform(0.2, 1.0), flat]
    q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    a = np.cov((pts @ q.T).T, bias=True)
    w, v = np.linalg.eigh(a)
    ok, w0, w1, w2, n0, n1, n2 = _solve(a)
    gap = (w[1] - w[0]) / w[2]
    if not ok:
        assert gap < 1e-5
        return
    assert np.allclose([w0, w1, w2], w, rtol=0, atol=1e-12 * w[2])
    assert abs(np.linalg.norm([n0, n1, n2]) - 1.0) < 1e-12
    assert abs(np.dot([n0, n1, n2], v[:, 0])) > 1.0 - 1e-9 / gap**2


def test_normals_and_curvature_from_moments_as_with_lapack():
    """The whole ``_normal_of`` (moments -> covariance -> normal, curvature) on many voxels."""
    rng = np.random.default_rng(7)
    sums = []
    for _ in range(500):
        pts = rng.normal(0, 1, (20, 3)) * [1.0, 0.5, rng.uniform(0.001, 0.2)] + rng.normal(0, 100, 3)
        x, y, z = pts.T
        sums.append([len(pts), *pts.sum(0), (x * x).sum(), (x * y).sum(), (x * z).sum(), (y * y).sum(),
                     (y * z).sum(), (z * z).sum()])  # fmt: skip
    sums = np.array(sums)
    normals, curvature = M._normals_from_sums(sums)
    for r, n, cv in zip(sums, normals, curvature, strict=True):
        c = r[0]
        m = r[1:4] / c
        cov = np.array([[r[4], r[5], r[6]], [r[5], r[7], r[8]], [r[6], r[8], r[9]]]) / c - np.outer(m, m)
        w, v = np.linalg.eigh(cov)
        assert abs(cv - w[0] / w.sum()) < 1e-9
        assert abs(abs(np.dot(n, v[:, 0])) - 1.0) < 1e-6
