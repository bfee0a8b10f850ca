"""Degeneracy of a registration: which motions the matched surfaces cannot see.

Zhang, Kaess and Singh (ICRA 2016, "On degeneracy of optimization-based state estimation
problems") judge a registration by the eigenvalues of the normal matrix ``J^T J`` of its
linearised constraints at the solution; X-ICP (Tuna et al., T-RO 2023) does the same per motion
direction ("localizability"). With KISS-ICP's *point-to-point* residuals ``J^T J`` cannot show a
degeneracy: the translation block is ``sum(w_i) I`` whatever the geometry, because a point's
residual to its nearest map point is a 3-vector even on a featureless wall (the nearest point
merely slides with the pose). What a correspondence really constrains is the distance to the
*surface* it lies on. Here each correspondence of the final pose (each source point's nearest
map point within KISS-ICP's 3 sigma, in the map's 27 voxels around it, with KISS-ICP's
Geman-McClure weight) is given the point-to-plane information of the surface it matched, from
the map points of the matched point's voxel (KISS-ICP's map: up to 20 a voxel, no two closer
than voxel / sqrt(20); those within half a voxel when the voxel holds too few):
the normal ``n`` is the covariance's eigenvector of the smallest eigenvalue, weighted by the
planarity ``1 - s3 / s2`` (``s_k`` the square roots of the eigenvalues, descending): 1 on a plane,
0 where the smallest two spreads are alike (one scan line's points, a scatter of leaves, an edge:
no normal to trust). The points of one scan line crossing a voxel are a line, not a plane, and
would otherwise claim a constraint across the line that the surface does not give.

The 6x6 information ``H = sum w_i J_i^T Omega_i J_i`` (``J_i = [I, -[p_i]x]``, ``p_i`` in the
sensor frame, perturbation on the right, ``Omega_i = planarity n n^T``) has the units of "matched
plane points". The rotation about each sensor axis is scaled by the correspondences' RMS distance
from that axis (its lever arm: a rotation by ``theta`` moves them by about ``arm theta``), so that
all six directions are in metres; in a tunnel the roll's arm is the cross-section's few metres,
not the tens of metres of range. A direction whose information is below ``ratio`` times the best
direction's is *degenerate*: its error standard deviation is more than ``1 / sqrt(ratio)`` times
the best direction's. The default 0.01 is ten times the best direction's error. Measured with
``scripts/odometry_acceptance.py``: the normals' own noise gives a featureless tunnel's axis at
most 0.009 (every frame beyond the entrance's reach, raw and prc, 400-frame hdl64 drive); the
weakest frames of structured drives are at least 0.015 (the yaw of a walker starting out in a
windy forest, vlp16: its stems' faces point at the sensor) and 0.05 (urban hdl64 drives), from
the guard's warm-up on (before it the map holds too few points a voxel to show its surfaces).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from prc_slam.odometry.guard import nearest_map_point
from prc_slam.util.voxels import find

#: a neighbourhood with fewer map points than this has no surface to speak of
MIN_NEIGHBOURS = 5


class DegeneracyConfig(BaseModel):
    """Degeneracy of each frame's registration (:mod:`prc_slam.odometry.degeneracy`)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="compute each frame's conditioning and flag degenerate directions")
    ratio: float = Field(
        0.01,
        gt=0,
        lt=1,
        description="a direction with less information than this share of the best direction's is degenerate "
        "(its error standard deviation over 1/sqrt(ratio) times the best's: 10x at 0.01); measured: a featureless "
        "tunnel's axis <= 0.009, structured drives' weakest frames >= 0.015",
    )
    keep_prediction: bool = Field(
        True,
        description="along a degenerate direction keep the constant-velocity prediction: the registration's "
        "correction is projected onto the well-constrained directions",
    )


@dataclass
class Conditioning:
    """One frame's conditioning.

    Attributes
    ----------
    eigenvalues : float (6,)
        Of the scaled information, ascending.
    eigenvectors : float (6, 6)
        Columns: twist directions ``(t, L * w)`` in the sensor frame, scaled.
    scale : float (3,)
        ``L``: the correspondences' RMS distance from each axis of the sensor frame (m), the lever
        arm of a rotation about it.
    correspondences : int
    degenerate : int
        How many of the directions (the first ones) are degenerate.
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    scale: np.ndarray
    correspondences: int
    degenerate: int

    @property
    def ratio(self) -> float:
        """Smallest over largest eigenvalue (0 without information)."""
        top = float(self.eigenvalues[-1])
        return float(self.eigenvalues[0]) / top if top > 0 else 0.0

    def directions(self) -> list[dict]:
        """Each degenerate direction: ``kind`` (``"translation"`` when most of the scaled
        direction is a translation, else ``"rotation"``), ``direction`` (unit vector in the sensor
        frame: the translation, or the rotation's axis) and ``ratio`` (its information over the
        best direction's)."""
        out = []
        top = float(self.eigenvalues[-1])
        for k in range(self.degenerate):
            v = self.eigenvectors[:, k]
            trans, rot = v[:3], v[3:]
            kind = "translation" if trans @ trans >= rot @ rot else "rotation"
            u = trans if kind == "translation" else rot
            u = u / max(float(np.linalg.norm(u)), 1e-12)
            if u[np.argmax(np.abs(u))] < 0:  # a sign for reading: the largest component positive
                u = -u
            ratio = float(self.eigenvalues[k]) / top if top > 0 else 0.0
            out.append({"kind": kind, "direction": [round(float(x), 4) for x in u], "ratio": ratio})
        return out

    def project(self, xi: np.ndarray) -> np.ndarray:
        """The twist ``xi = (t, w)`` (sensor frame) without its components along the degenerate
        directions (in the scaled coordinates the eigenvectors are orthonormal)."""
        scale = np.concatenate([np.ones(3), self.scale])
        y = np.asarray(xi, dtype=np.float64) * scale
        V = self.eigenvectors[:, : self.degenerate]
        return (y - V @ (V.T @ y)) / scale


@njit(cache=True, nogil=True)
def _surface(m, g, table, coords, first, count, mpts, inv_voxel):
    """Normal and planarity, direction and linearity of the surface at map point ``m`` of group
    ``g``: the map points of its voxel (KISS-ICP's map keeps up to 20 a voxel, no two closer than
    voxel / sqrt(20)), or, when the voxel holds fewer than :data:`MIN_NEIGHBOURS` (a stem
    split by a voxel face), those within half a voxel of it; zero shares with fewer still."""
    n = np.zeros(3)
    d = np.zeros(3)
    s = np.zeros(3)
    cov = np.zeros((3, 3))
    c = np.empty(3, np.int64)
    for a in range(3):
        c[a] = np.int64(np.floor(m[a] * inv_voxel))
    v = find(table, coords, c[0], c[1], c[2] * 8 + g)
    own = v >= 0 and count[v] >= MIN_NEIGHBOURS
    half = 0.5 / inv_voxel
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for a in range(3):  # the voxel itself, or the voxels the ball of half a voxel around m touches
        lo[a] = c[a] if own else np.int64(np.floor((m[a] - half) * inv_voxel))
        hi[a] = c[a] if own else np.int64(np.floor((m[a] + half) * inv_voxel))
    r2 = np.inf if own else half * half
    k = 0
    for kx in range(lo[0], hi[0] + 1):
        for ky in range(lo[1], hi[1] + 1):
            for kz in range(lo[2], hi[2] + 1):
                v = find(table, coords, kx, ky, kz * 8 + g)
                if v < 0:
                    continue
                for q in range(first[v], first[v] + count[v]):
                    e0, e1, e2 = mpts[q, 0] - m[0], mpts[q, 1] - m[1], mpts[q, 2] - m[2]
                    if e0 * e0 + e1 * e1 + e2 * e2 > r2:
                        continue
                    k += 1
                    s[0] += e0
                    s[1] += e1
                    s[2] += e2
                    cov[0, 0] += e0 * e0
                    cov[0, 1] += e0 * e1
                    cov[0, 2] += e0 * e2
                    cov[1, 1] += e1 * e1
                    cov[1, 2] += e1 * e2
                    cov[2, 2] += e2 * e2
    if k < MIN_NEIGHBOURS:
        return n, 0.0, d, 0.0
    mean = s / k
    for a in range(3):
        for b in range(a, 3):
            cov[a, b] = cov[a, b] / k - mean[a] * mean[b]
            cov[b, a] = cov[a, b]
    w, V = np.linalg.eigh(cov)  # ascending
    s3, s2, s1 = np.sqrt(max(w[0], 0.0)), np.sqrt(max(w[1], 0.0)), np.sqrt(max(w[2], 0.0))
    if s2 <= 0 or s1 <= 0:
        return n, 0.0, d, 0.0
    n[:] = V[:, 0]
    d[:] = V[:, 2]
    return n, 1.0 - s3 / s2, d, 1.0 - s2 / s1


@njit(cache=True, nogil=True)
def _add_line(H, c, R, dw, x, y, z):
    """``H += c J^T (I - d d^T) J`` for the point ``(x, y, z)`` (sensor frame) on a line of world
    direction ``dw`` (``J = [I, -[x]_x]``)."""
    d0 = R[0, 0] * dw[0] + R[1, 0] * dw[1] + R[2, 0] * dw[2]
    d1 = R[0, 1] * dw[0] + R[1, 1] * dw[1] + R[2, 1] * dw[2]
    d2 = R[0, 2] * dw[0] + R[1, 2] * dw[1] + R[2, 2] * dw[2]
    J = np.zeros((3, 6))
    J[0, 0] = J[1, 1] = J[2, 2] = 1.0
    J[0, 4], J[0, 5] = z, -y
    J[1, 3], J[1, 5] = -z, x
    J[2, 3], J[2, 4] = y, -x
    b = np.empty(6)
    for r in range(6):
        b[r] = J[0, r] * d0 + J[1, r] * d1 + J[2, r] * d2
    for r in range(6):
        for s_ in range(6):
            jj = J[0, r] * J[0, s_] + J[1, r] * J[1, s_] + J[2, r] * J[2, s_]
            H[r, s_] += c * (jj - b[r] * b[s_])


@njit(cache=True, nogil=True)
def information(src, src_group, table, coords, first, count, mpts, inv_voxel, max_d2, kernel, T, stride, lines):
    """The 6x6 information of the correspondences of ``src`` (sensor frame) at pose ``T``
    (module docstring), every ``stride``-th source point; with the correspondence count and the
    weighted mean squared distance of the matched points from each axis of the sensor frame.
    With ``lines``, a line-like neighbourhood (linearity ``1 - s2 / s1``: a stem's points along
    its axis) also constrains the two directions across its axis, ``linearity (I - d d^T)``:
    for the anchors' stems, whose points in a voxel are an upright line, not a plane."""
    R = T[:3, :3].copy()
    t = T[:3, 3].copy()
    H = np.zeros((6, 6))
    p = np.empty(3)
    a = np.empty(6)
    n = 0
    arm2 = np.zeros(3)
    wsum = 0.0
    for i in range(0, src.shape[0], stride):
        for k in range(3):
            p[k] = R[k, 0] * src[i, 0] + R[k, 1] * src[i, 1] + R[k, 2] * src[i, 2] + t[k]
        q, d2 = nearest_map_point(p, src_group[i], table, coords, first, count, mpts, inv_voxel, max_d2)
        if q < 0:
            continue
        nw, planarity, dw, linearity = _surface(mpts[q], src_group[i], table, coords, first, count, mpts, inv_voxel)
        w = kernel * kernel / ((kernel + d2) * (kernel + d2))  # KISS-ICP's Geman-McClure weight
        x, y, z = src[i, 0], src[i, 1], src[i, 2]
        n += 1
        arm2[0] += w * (y * y + z * z)
        arm2[1] += w * (x * x + z * z)
        arm2[2] += w * (x * x + y * y)
        wsum += w
        if lines and linearity > 0:
            _add_line(H, w * linearity, R, dw, x, y, z)
        if planarity <= 0:
            continue
        # the normal in the sensor frame, and J^T n = (n, x cross n): the change of the distance to
        # the plane under the twist (dt, dw) of the sensor pose (R (x + dt + dw cross x) + t)
        n0 = R[0, 0] * nw[0] + R[1, 0] * nw[1] + R[2, 0] * nw[2]
        n1 = R[0, 1] * nw[0] + R[1, 1] * nw[1] + R[2, 1] * nw[2]
        n2 = R[0, 2] * nw[0] + R[1, 2] * nw[1] + R[2, 2] * nw[2]
        a[0], a[1], a[2] = n0, n1, n2
        a[3], a[4], a[5] = y * n2 - z * n1, z * n0 - x * n2, x * n1 - y * n0
        c = w * planarity
        for r in range(6):
            for s_ in range(6):
                H[r, s_] += c * a[r] * a[s_]
    return H, n, (arm2 / wsum if wsum > 0 else arm2)


def conditioning(H: np.ndarray, n: int, arm2: np.ndarray, ratio: float) -> Conditioning:
    """The eigen-decomposition of ``H`` with the rotation about each axis scaled by its lever
    arm (``sqrt(arm2)``, the correspondences' RMS distance from that axis), and how many of its
    directions have less than ``ratio`` of the best direction's information."""
    arm2 = np.asarray(arm2, dtype=np.float64)
    scale = np.where(arm2 > 0, np.sqrt(np.maximum(arm2, 0.0)), 1.0)
    S = np.concatenate([np.ones(3), 1.0 / scale])
    Hs = H * S[:, None] * S[None, :]
    Hs = 0.5 * (Hs + Hs.T)
    w, V = np.linalg.eigh(Hs)
    w = np.maximum(w, 0.0)
    top = float(w[-1])
    degenerate = int(np.count_nonzero(w < ratio * top)) if top > 0 else 0
    return Conditioning(w, V, scale, int(n), min(degenerate, 6))


def block_ratio(H: np.ndarray, arm2: np.ndarray, axes: tuple[int, ...]) -> float:
    """Smallest over largest eigenvalue of the scaled information restricted to the twist
    components ``axes`` (e.g. ``(0, 1, 5)``: x, y and the rotation about z); 0 without
    information."""
    arm2 = np.asarray(arm2, dtype=np.float64)
    S = np.concatenate([np.ones(3), 1.0 / np.where(arm2 > 0, np.sqrt(np.maximum(arm2, 0.0)), 1.0)])
    idx = np.asarray(axes)
    block = (H * S[:, None] * S[None, :])[np.ix_(idx, idx)]
    w = np.linalg.eigvalsh(0.5 * (block + block.T))
    return float(max(w[0], 0.0) / w[-1]) if w[-1] > 0 else 0.0


def surface_information(
    source: np.ndarray,
    groups: np.ndarray,
    index: tuple[np.ndarray, ...],
    voxel: float,
    sigma: float,
    pose: np.ndarray,
    max_points: int = 600,
    lines: bool = False,
) -> tuple[np.ndarray, int, np.ndarray]:
    """:func:`information` of registering ``source`` (sensor frame, class group per point) to a
    :class:`~prc_slam.odometry.group_map.GroupVoxelMap` (``index``) at ``pose``, with KISS-ICP's
    correspondences (within ``3 sigma``, weight of kernel ``sigma``) and surfaces within one
    ``voxel`` of each matched map point; at most ``max_points`` source points (evenly strided:
    the eigenvalues' ratios do not depend on the count); ``lines``: see :func:`information`.
    Returns ``(H, correspondences, arm2)``."""
    stride = max(1, int(np.ceil(len(source) / max_points)))
    return information(
        np.ascontiguousarray(source, dtype=np.float64), np.ascontiguousarray(groups, dtype=np.int64), *index,
        1.0 / voxel, (3.0 * sigma) ** 2, float(sigma), np.ascontiguousarray(pose, dtype=np.float64), stride, lines,
    )  # fmt: skip


def analyse(
    source: np.ndarray,
    groups: np.ndarray,
    index: tuple[np.ndarray, ...],
    voxel: float,
    sigma: float,
    pose: np.ndarray,
    ratio: float,
    max_points: int = 600,
) -> Conditioning:
    """The :class:`Conditioning` of registering ``source`` at ``pose`` (:func:`surface_information`)."""
    H, n, arm2 = surface_information(source, groups, index, voxel, sigma, pose, max_points)
    return conditioning(H, n, arm2, ratio)


__all__ = [
    "Conditioning",
    "DegeneracyConfig",
    "analyse",
    "block_ratio",
    "conditioning",
    "information",
    "surface_information",
]
