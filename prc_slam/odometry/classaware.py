"""Class-aware registration: correspondences never cross class groups (PRC paper, Sec. V:
"points belonging to the same class can be matched together").

KISS-ICP's pipeline with the map split by class group: each group of the frame is deskewed by
KISS-ICP's preprocessor (constant-velocity model) and downsampled with KISS-ICP's voxel filter
(0.5 and 1.5 voxel sizes), with KISS-ICP's adaptive threshold. KISS-ICP's voxel map and
registration cannot carry labels, so those two are ours, in numba: :class:`GroupVoxelMap`
(KISS-ICP's map rules, keyed by voxel and group) and :func:`icp` (KISS-ICP's point-to-point
Gauss-Newton with the Geman-McClure kernel of the adaptive threshold sigma, weight
``sigma^2 / (sigma + r^2)^2``, correspondences within 3 sigma), each residual further weighted
by its group's weight.

Each group's residual follows its geometry (``residuals``; all "point" is the registration
above): a trunk point is matched to the *line* of its stem (the matched map point's
neighbourhood's direction: the PRC paper's Sec. V-A names line and cylinder regression for stems),
whose offset along the stem is the map's sampling, not motion, so that the stems fix x, y, yaw
(and roll and pitch by their height) and not the height; a ground point to its *plane*
(Chen and Medioni 1992), fixing height, roll and pitch and not the slide along the ground.

Within the sweep (``sweep_motion``): the error left after deskewing again (``odometry.redeskew``)
on a forest walk is per-frame jitter, not drift, and it follows the walker's acceleration
(simulated vlp16 walk, seed 1, 150 frames: the pitch error's correlation with the pitch
acceleration 0.81, the yaw's 0.92, the height's with the pitch acceleration -0.74): deskewing
with the motion from the previous frame to this one applies the velocity of half a frame ago, and
a 2 Hz step changes it within a frame. :func:`icp_sweep` therefore registers the sweep once more
with its velocity among the unknowns (continuous time within the sweep, as CT-ICP estimates a
sweep's begin and end poses), each point at its time from the sweep's azimuth (:func:`sweep_times`),
and the frame is deskewed with the velocity found for the map and the ground refinement.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from prc_slam import labels as L
from prc_slam.odometry.degeneracy import _surface, block_ratio, surface_information
from prc_slam.odometry.ground import GroundModel
from prc_slam.odometry.group_map import GroupVoxelMap
from prc_slam.odometry.guard import OdometryFailure, check_pose, is_rigid, nearest_map_point, orthonormal
from prc_slam.odometry.kiss import (
    MIN_SOURCE_POINTS,
    GuardedOdometry,
    KissOdometry,
    OdometryConfig,
    _deskew_kernel,
    deskew_points,
    kiss_config,
    se3_exp,
    se3_log,
)

#: class groups and the codes they hold; codes not listed fall into "other"
GROUPS: dict[str, tuple[int, ...]] = {
    "trunk": (L.TRUNK,),
    "structure": (L.BUILDING, L.POLE),
    "ground": (L.GROUND, L.CURB),
    "vegetation": (L.VEGETATION,),
    "other": (),
}
GROUP_NAMES = tuple(GROUPS)
_OTHER = GROUP_NAMES.index("other")
#: the group whose points anchor the class-aware registration (PRC's trunks in forest mode)
ANCHOR_GROUP = GROUP_NAMES.index("trunk")
#: the twist components anchors on upright stems constrain: x, y and the rotation about z
#: (sensor frame); stems say nothing of the height, which the ground gives either way
ANCHOR_AXES = (0, 1, 5)


def group_of_codes() -> np.ndarray:
    """``uint8[256]``: group index of every label code."""
    table = np.full(256, _OTHER, dtype=np.uint8)
    for gi, codes in enumerate(GROUPS.values()):
        table[list(codes)] = gi
    return table


#: per-group weights by PRC mode, measured (README): in urban mode the spared one-sided "noise"
#: in ``other`` is mostly thin poles, worth full weight; in forest mode it is crown and stem edges
WEIGHTS = {
    "urban": {"trunk": 1.0, "structure": 1.0, "ground": 1.0, "vegetation": 0.5, "other": 1.0},
    "forest": {"trunk": 1.0, "structure": 1.0, "ground": 1.0, "vegetation": 0.1, "other": 0.5},
}

#: residual of each group's correspondences (PRC paper, Sec. V-A: stems found by line or cylinder
#: regression; :class:`ClassAwareConfig`): trunks to their stem's line, ground to its plane
RESIDUALS = {"trunk": "line", "ground": "plane"}
#: residual kinds of :attr:`ClassAwareConfig.residuals`, by code
RESIDUAL_KINDS = ("point", "line", "plane")


class ClassAwareConfig(BaseModel):
    """Per-group weights of the residuals (0 leaves a group out of the registration; its map is
    still kept). Defaults: the urban weights; :meth:`for_mode` gives those of a PRC mode."""

    model_config = ConfigDict(extra="forbid")

    weights: dict[str, float] = Field(default_factory=lambda: dict(WEIGHTS["urban"]))
    fallback: bool = Field(
        True,
        description="register a sweep as the prc variant does (KISS-ICP on the same points) unless its anchors (the "
        "trunk group, matched at the predicted pose) constrain x, y and yaw on their own: no degenerate direction "
        "by odometry.degeneracy.ratio (one stem leaves the yaw and the tangential shift confounded; two apart do "
        "not); classaware_frames lists the sweeps matched class-aware",
    )

    residuals: dict[str, Literal["point", "line", "plane"]] = Field(
        default_factory=lambda: dict(RESIDUALS),
        description="residual of each group's correspondences (groups not listed: point): point (KISS-ICP's point to "
        "point), line (point to the line through the matched map point along its neighbourhood's direction: an "
        "upright stem fixes the two directions across it, x, y and, from stems apart, yaw; along it a nearest "
        "point's offset is sampling, not motion) or plane (point to the plane of its neighbourhood: the ground fixes "
        "height, roll and pitch; its offsets along the plane are sampling); all point: the registration before these",
    )
    min_shape: float = Field(
        0.5,
        ge=0,
        le=1,
        description="a matched map point whose neighbourhood's linearity (line) or planarity (plane) is below this "
        "keeps point to point",
    )

    sweep_motion: bool = Field(
        True,
        description="after the registration (and deskewing again), register the sweep once more with its velocity "
        "among the unknowns (classaware.icp_sweep: continuous time within the sweep, as CT-ICP) and deskew the frame "
        "with the velocity found (one beyond the guard's speed or turn-rate bound is not believed: the frame keeps its "
        "registration, in sweep_rejected); false: the constant-velocity deskewing only",
    )
    sweep_prior: float = Field(
        0.05,
        ge=0,
        description="weight of the prior that ties the sweep's velocity to the motion it was deskewed with, as a "
        "fraction of the pose's own information per axis",
    )

    @classmethod
    def for_mode(cls, mode: str) -> ClassAwareConfig:
        if mode not in WEIGHTS:
            raise ValueError(f"no class-aware weights for PRC mode {mode!r}; modes are {sorted(WEIGHTS)}")
        return cls(weights=dict(WEIGHTS[mode]))

    def kind_array(self) -> np.ndarray:
        """``int64[G]``: the residual kind of every group (index into :data:`RESIDUAL_KINDS`)."""
        unknown = set(self.residuals) - set(GROUP_NAMES)
        if unknown:
            raise ValueError(f"unknown class groups {sorted(unknown)}; groups are {list(GROUP_NAMES)}")
        return np.array([RESIDUAL_KINDS.index(self.residuals.get(g, "point")) for g in GROUP_NAMES], np.int64)

    def weight_array(self) -> np.ndarray:
        unknown = set(self.weights) - set(GROUP_NAMES)
        if unknown:
            raise ValueError(f"unknown class groups {sorted(unknown)}; groups are {list(GROUP_NAMES)}")
        return np.array([float(self.weights.get(g, 1.0)) for g in GROUP_NAMES])


@njit(cache=True, nogil=True)
def _exp_se3(dx):
    """4x4 transform of the twist ``(t, w)`` (translation first, as KISS-ICP's Sophus update)."""
    w = dx[3:]
    theta = np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-12:
        R = np.eye(3) + K
        V = np.eye(3) + 0.5 * K
    else:
        a = np.sin(theta) / theta
        b = (1 - np.cos(theta)) / theta**2
        c = (1 - a) / theta**2
        K2 = K @ K
        R = np.eye(3) + a * K + b * K2
        V = np.eye(3) + b * K + c * K2
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = V @ dx[:3]
    return T


@njit(cache=True, nogil=True)
def _projector(P, kind, m, g, table, coords, first, count, mpts, inv_voxel, min_shape):
    """``P`` (3x3) for the residual ``P (p - q)`` of a correspondence to map point ``m`` of group
    ``g``: ``I`` (point to point, KISS-ICP's), ``I - d d^T`` (point to line: the line through ``m``
    along the direction ``d`` of its neighbourhood) or ``n n^T`` (point to plane: the plane through
    ``m`` of normal ``n``), from the neighbourhood's covariance (:func:`~.degeneracy._surface`:
    its voxel's map points, KISS-ICP's up to 20). A neighbourhood whose linearity (line) or
    planarity (plane) is below ``min_shape`` keeps point to point."""
    for a in range(3):
        for e in range(3):
            P[a, e] = 1.0 if a == e else 0.0
    if kind == 0:
        return
    nrm, planarity, d, linearity = _surface(m, g, table, coords, first, count, mpts, inv_voxel)
    if kind == 1 and linearity >= min_shape:
        for a in range(3):
            for e in range(3):
                P[a, e] -= d[a] * d[e]
    elif kind == 2 and planarity >= min_shape:
        for a in range(3):
            for e in range(3):
                P[a, e] = nrm[a] * nrm[e]


@njit(cache=True, nogil=True, inline="always")
def _correspondence(i, src, src_group, weights, kernel, R, t, p, r, Pr, kinds, min_shape, table, coords, first, count,
                    mpts, inv_voxel, max_d2, matched, projectors):  # fmt: skip
    """Source point ``i`` at the pose ``(R, t)``: ``p`` (world), the residual ``r`` to its nearest
    map point of its group ``g`` and ``Pr = P r`` with the point's projector (computed again only
    when it matches another map point: ``matched``, ``projectors`` as :func:`_linearise`'s).
    Returns the map point (-1: none within ``sqrt(max_d2)``, or the group weighs nothing), ``g``
    and the correspondence's weight: the group's times the Geman-McClure weight of ``|P r|^2``."""
    g = src_group[i]
    if weights[g] <= 0:
        return -1, g, 0.0
    for k in range(3):
        p[k] = R[k, 0] * src[i, 0] + R[k, 1] * src[i, 1] + R[k, 2] * src[i, 2] + t[k]
    q = nearest_map_point(p, g, table, coords, first, count, mpts, inv_voxel, max_d2)[0]
    if q < 0:
        return q, g, 0.0
    r[0], r[1], r[2] = p[0] - mpts[q, 0], p[1] - mpts[q, 1], p[2] - mpts[q, 2]
    P = projectors[i]
    if matched[i] != q:
        _projector(P, kinds[g], mpts[q], g, table, coords, first, count, mpts, inv_voxel, min_shape)
        matched[i] = q
    for k in range(3):
        Pr[k] = P[k, 0] * r[0] + P[k, 1] * r[1] + P[k, 2] * r[2]
    rr = Pr[0] * r[0] + Pr[1] * r[1] + Pr[2] * r[2]
    return q, g, weights[g] * kernel * kernel / ((kernel + rr) * (kernel + rr))


@njit(cache=True, nogil=True, inline="always")
def _accumulate(H, b, w, J, P, Pr, PJ):
    """One correspondence into the normal equations: ``H += w J^T P J`` (upper triangle) and
    ``b += w J^T P r`` (``Pr = P r``), ``J`` of shape ``(3, m)``; ``PJ`` a ``(3, m)`` buffer."""
    m = J.shape[1]
    for k in range(3):
        for a in range(m):
            PJ[k, a] = P[k, 0] * J[0, a] + P[k, 1] * J[1, a] + P[k, 2] * J[2, a]
    for a in range(m):
        ja0, ja1, ja2 = J[0, a], J[1, a], J[2, a]
        b[a] += w * (ja0 * Pr[0] + ja1 * Pr[1] + ja2 * Pr[2])
        for e in range(a, m):
            H[a, e] += w * (ja0 * PJ[0, e] + ja1 * PJ[1, e] + ja2 * PJ[2, e])


@njit(cache=True, nogil=True)
def _linearise(
    src, src_group, weights, kinds, min_shape, table, coords, first, count, mpts, inv_voxel, max_d2, kernel, T,
    n_chunks, matched, projectors,
):  # fmt: skip
    """Gauss-Newton normal equations at ``T``, accumulated per chunk of source points (serially:
    numba's thread pool, spinning on a machine whose cores are busy, cost 12x the work itself on
    the forest walk, 870 vs 70 ms per frame): ``H (C, 6, 6)``, ``b (C, 6)``, correspondences
    per chunk and group, and the group matched by each source point (-1: none).

    Each correspondence's residual is ``P (p - q)`` with the projector of its group's residual
    kind (``kinds``, :func:`_projector`): ``H += w J^T P J``, ``b += w J^T P r`` (``P`` symmetric
    and idempotent), the Geman-McClure weight ``w`` of the projected residual. ``matched`` (n,) and
    ``projectors`` (n, 3, 3) keep each source point's map point and projector from one iteration to
    the next (the map does not change within a registration): a projector is computed again only
    when its point matches another map point (``matched`` -1 at first)."""
    n = src.shape[0]
    G = weights.shape[0]
    H = np.zeros((n_chunks, 6, 6))
    b = np.zeros((n_chunks, 6))
    counts = np.zeros((n_chunks, G), np.int64)
    partner = np.full(n, -1, np.int64)
    R = T[:3, :3]
    t = T[:3, 3]
    step = (n + n_chunks - 1) // n_chunks
    for c in range(n_chunks):
        p = np.empty(3)
        r = np.empty(3)
        Pr = np.empty(3)
        J = np.zeros((3, 6))
        PJ = np.zeros((3, 6))
        J[0, 0] = J[1, 1] = J[2, 2] = 1.0
        Hc, bc = H[c], b[c]
        for i in range(c * step, min(n, (c + 1) * step)):
            q, g, w = _correspondence(i, src, src_group, weights, kernel, R, t, p, r, Pr, kinds, min_shape, table,
                                      coords, first, count, mpts, inv_voxel, max_d2, matched, projectors)  # fmt: skip
            if q < 0:
                continue
            counts[c, g] += 1
            partner[i] = g
            # J = [I, -[p]x]; only its rotational block changes from point to point
            J[0, 4], J[0, 5] = p[2], -p[1]
            J[1, 3], J[1, 5] = -p[2], p[0]
            J[2, 3], J[2, 4] = p[1], -p[0]
            _accumulate(Hc, bc, w, J, projectors[i], Pr, PJ)
    return H, b, counts, partner


#: fewer correspondences than this end the ICP at its current estimate (6 unknowns)
MIN_CORRESPONDENCES = 12
#: eigenvalues of H below this fraction of the largest are directions the correspondences do
#: not constrain (one plane, one line, one group): the update leaves them alone
DEGENERATE_RATIO = 1e-6


@njit(cache=True, nogil=True)
def _solve_constrained(H, b):
    """``dx = -H^+ b`` restricted to the well-constrained eigen-directions of ``H`` (Zhang,
    Kaess and Singh, ICRA 2016: solution remapping for degenerate optimisation); ``ok`` is False
    when ``H`` or ``b`` is not finite or nothing is constrained. Collinear, coplanar or too few
    correspondences then give a partial (or no) update instead of a NaN. Any size (6: the pose;
    12: the pose and the sweep's velocity)."""
    dx = np.zeros(b.shape[0])
    if not (np.isfinite(H).all() and np.isfinite(b).all()):
        return dx, False
    w, V = np.linalg.eigh(H)
    top = w[-1]
    if not top > 0:
        return dx, False
    proj = V.T @ b
    for k in range(b.shape[0]):
        if w[k] > DEGENERATE_RATIO * top:
            dx -= V[:, k] * (proj[k] / w[k])
    return dx, bool(np.isfinite(dx).all())


@njit(cache=True, nogil=True)
def icp(
    src, src_group, weights, table, coords, first, count, mpts, voxel, T0, max_dist, kernel, max_iter, tol,
    kinds=None, min_shape=0.5,
):  # fmt: skip
    """Gauss-Newton ICP of ``src`` (sensor frame) to the group maps (KISS-ICP's update:
    ``T <- exp(dx) T`` until ``|dx| < tol``), point to point unless ``kinds`` says otherwise.

    Parameters
    ----------
    src : float (n, 3)
    src_group : int (n,)
        Group of each source point; it is matched only to map points of that group.
    weights : float (G,)
        Per-group weight of the residuals.
    kinds : int (G,), optional
        Residual of each group (index into :data:`RESIDUAL_KINDS`: point, line, plane); default:
        point to point for every group (KISS-ICP's).
    min_shape : float
        Linearity or planarity below which a neighbourhood keeps point to point.
    T0 : float (4, 4)
        Initial guess.
    max_dist, kernel : float
        Correspondence distance (3 sigma) and Geman-McClure scale (sigma).

    Returns
    -------
    T : float (4, 4)
    counts : int64 (G,)
        Correspondences per group in the last iteration.
    partner_group : int64 (n,)
        Group of the map point matched to each source point in the last iteration (-1: none).
    iterations : int
    """
    T = T0.copy()
    if kinds is None:
        kinds = np.zeros(weights.shape[0], np.int64)
    counts = np.zeros(weights.shape[0], np.int64)
    partner = np.full(src.shape[0], -1, np.int64)
    matched = np.full(src.shape[0], -1, np.int64)
    projectors = np.empty((src.shape[0], 3, 3))
    iterations = 0
    while iterations < max_iter:
        iterations += 1
        Hc, bc, cc, partner = _linearise(
            src, src_group, weights, kinds, min_shape, table, coords, first, count, mpts, 1.0 / voxel,
            max_dist * max_dist, kernel, T, 8, matched, projectors,
        )  # fmt: skip
        H = Hc.sum(axis=0)
        b = bc.sum(axis=0)
        counts = cc.sum(axis=0)
        for a in range(6):
            for e in range(a):
                H[a, e] = H[e, a]
        if counts.sum() < MIN_CORRESPONDENCES:
            break
        dx, ok = _solve_constrained(H, b)
        if not ok:
            break
        T = _exp_se3(dx) @ T
        if np.sqrt((dx * dx).sum()) < tol:
            break
    return T, counts, partner, iterations


@njit(cache=True, nogil=True)
def _linearise_sweep(src, s, src_group, weights, kinds, min_shape, table, coords, first, count, mpts, inv_voxel, max_d2,
                     kernel, T, matched, projectors):  # fmt: skip
    """The normal equations of :func:`_linearise` in the pose and the sweep's velocity: 12 unknowns,
    ``(dx, dv)``, the residual of point ``i`` (deskewed to the reference instant, ``s_i`` its time
    from it in frame intervals) moving by ``J dx + s_i R [I, -[p_i]x] dv`` (``R`` the pose's
    rotation, ``p_i`` the deskewed point: a change ``dv`` of the velocity moves it by
    ``exp(s_i dv)``; ``matched``, ``projectors``: as :func:`_linearise`'s). ``H (12, 12)``, ``b (12,)``,
    correspondences per group, the weight sum."""
    G = weights.shape[0]
    H = np.zeros((12, 12))
    b = np.zeros(12)
    counts = np.zeros(G, np.int64)
    R = T[:3, :3]
    t = T[:3, 3]
    p = np.empty(3)
    r = np.empty(3)
    Pr = np.empty(3)
    J = np.zeros((3, 12))
    PJ = np.zeros((3, 12))
    wsum = 0.0
    for i in range(src.shape[0]):
        q, g, w = _correspondence(i, src, src_group, weights, kernel, R, t, p, r, Pr, kinds, min_shape, table, coords,
                                  first, count, mpts, inv_voxel, max_d2, matched, projectors)  # fmt: skip
        if q < 0:
            continue
        counts[g] += 1
        wsum += w
        for k in range(3):
            for a in range(12):
                J[k, a] = 0.0
            J[k, k] = 1.0
        J[0, 4], J[0, 5] = p[2], -p[1]
        J[1, 3], J[1, 5] = -p[2], p[0]
        J[2, 3], J[2, 4] = p[1], -p[0]
        x, y, z = src[i, 0], src[i, 1], src[i, 2]
        si = s[i]
        for k in range(3):  # s_i R [I, -[x]x]
            J[k, 6], J[k, 7], J[k, 8] = si * R[k, 0], si * R[k, 1], si * R[k, 2]
            J[k, 9] = si * (R[k, 1] * -z + R[k, 2] * y)
            J[k, 10] = si * (R[k, 0] * z + R[k, 2] * -x)
            J[k, 11] = si * (R[k, 0] * -y + R[k, 1] * x)
        _accumulate(H, b, w, J, projectors[i], Pr, PJ)
    for a in range(12):
        for e in range(a):
            H[a, e] = H[e, a]
    return H, b, counts, wsum


@njit(cache=True, nogil=True)
def icp_sweep(src0, s, src_group, weights, kinds, min_shape, table, coords, first, count, mpts, voxel, T0, max_dist,
              kernel, max_iter, tol, prior):  # fmt: skip
    """:func:`icp` with the sweep's velocity among the unknowns (continuous-time registration of
    one sweep, as CT-ICP, Dellenbach et al., ICRA 2022, estimates a sweep's begin and end poses):
    ``src0`` deskewed with the constant-velocity motion, ``s`` each point's time from the reference
    instant in frame intervals; each iteration deskews ``src0`` by the velocity correction ``v``
    found so far (``exp(s_i v)``) and solves for ``(dx, dv)``. ``prior`` ties ``v`` to 0 (the
    motion the frame was deskewed with) with ``prior`` times the pose's own information per axis.

    Returns
    -------
    T : float (4, 4)
    v : float (6,)
        Correction of the deskewing motion (twist per frame interval, translation first).
    counts : int64 (G,)
    iterations : int
    """
    T = T0.copy()
    v = np.zeros(6)
    counts = np.zeros(weights.shape[0], np.int64)
    src = src0.copy()
    matched = np.full(src0.shape[0], -1, np.int64)
    projectors = np.empty((src0.shape[0], 3, 3))
    iterations = 0
    inv_voxel = 1.0 / voxel
    while iterations < max_iter:
        iterations += 1
        H, b, counts, _ = _linearise_sweep(
            src, s, src_group, weights, kinds, min_shape, table, coords, first, count, mpts, inv_voxel,
            max_dist * max_dist, kernel, T, matched, projectors,
        )  # fmt: skip
        if counts.sum() < MIN_CORRESPONDENCES:
            break
        for a in range(6):  # the prior on the velocity correction: H_vv += prior diag(H_xx), b_v += ... v
            c = prior * H[a, a]
            H[6 + a, 6 + a] += c
            b[6 + a] += c * v[a]
        d, ok = _solve_constrained(H, b)
        if not ok:
            break
        T = _exp_se3(d[:6]) @ T
        v += d[6:]
        src = _deskew_kernel(src0, s, v)
        if np.sqrt((d * d).sum()) < tol:
            break
    return T, v, counts, iterations


def sweep_times(measured: np.ndarray, times: np.ndarray, points: np.ndarray, bins: int = 720) -> np.ndarray:
    """The acquisition time of each of ``points`` (sensor frame, downsampled from the frame) from
    the frame's ``measured`` points and ``times``: a spinning sensor's time follows the azimuth, so
    each point is given the mean time of the measured points in its azimuth bin (``bins`` over the
    turn); a bin without points gives the mean time of all."""

    def cell(xy: np.ndarray) -> np.ndarray:
        az = np.arctan2(xy[:, 1], xy[:, 0])
        return np.minimum(((az + np.pi) * (bins / (2 * np.pi))).astype(np.int64), bins - 1)

    k = cell(measured)
    n = np.bincount(k, minlength=bins)
    total = np.bincount(k, weights=times, minlength=bins)
    mean = np.where(n > 0, total / np.maximum(n, 1), float(np.mean(times)))
    return mean[cell(points)]


# ---- the odometry --------------------------------------------------------------------------


class IcpNotConverged(OdometryFailure):
    """The class-aware ICP ended at its iteration limit (``guard.fail_on_max_iterations``)."""


class ClassAwareOdometry(GuardedOdometry):
    """Frame-to-map odometry on a voxel map keyed by class group, with the guards, deskewing
    and health of :class:`~prc_slam.odometry.kiss.KissOdometry`.

    Parameters
    ----------
    config : OdometryConfig
        KISS-ICP's settings (voxel size, ranges, deskewing, thresholds, iterations).
    classes : ClassAwareConfig
    """

    def __init__(self, config: OdometryConfig | None = None, classes: ClassAwareConfig | None = None) -> None:
        from kiss_icp.preprocess import get_preprocessor
        from kiss_icp.threshold import get_threshold_estimator

        self.config = config or OdometryConfig()
        self.classes = classes or ClassAwareConfig()
        self.kiss_config = kiss_config(self.config)
        self.voxel = self.kiss_config.mapping.voxel_size
        self.preprocessor = get_preprocessor(self.kiss_config)
        self.adaptive_threshold = get_threshold_estimator(self.kiss_config)
        self.map = GroupVoxelMap(self.voxel, self.config.max_range, self.config.max_points_per_voxel)
        self.weights = self.classes.weight_array()
        self.kinds = self.classes.kind_array()
        self.group_of = group_of_codes()
        self.last_pose = np.eye(4)
        self.last_delta = np.eye(4)
        self._init_guard()
        self.correspondences: list[np.ndarray] = []  # per frame, per group
        self.iterations: list[int] = []
        #: the prc registration, kept in step, for the sweeps whose anchors do not hold the pose
        self.fallback = KissOdometry(self.config) if self.classes.fallback else None
        self.classaware_frames: list[int] = []  # frames registered class-aware (all of them without fallback)
        #: frames whose class-aware ICP ended at its iteration limit (registered as the prc variant does, or
        #: deskewed once when it was deskewing again)
        self.unconverged_frames: list[int] = []
        #: per frame with ``sweep_motion``, the correction of its deskewing motion (twist per frame interval)
        self.sweep_corrections: list[np.ndarray] = []
        #: frames whose registered sweep velocity broke the guard's bounds (kept as registered before it)
        self.sweep_rejected: list[int] = []
        #: per frame, the anchors' conditioning (smallest over largest information of x, y, yaw; None: not judged)
        self.anchor_ratio: list[float | None] = []
        #: the ground refinement (``odometry.ground``) of every sweep given labels: one ground model, shared with
        #: the prc registration it falls back on, so that both refine against the same ground
        self.ground: GroundModel | None = None
        self.ground_refined: list[int] = []  # frames whose height, roll and pitch it moved
        if self.fallback is not None:  # the frames either registration deskewed again, in one list
            self.redeskewed = self.fallback.redeskewed
        if self.config.ground.enabled:
            if self.fallback is not None:
                self.ground, self.ground_refined = self.fallback.ground, self.fallback.ground_refined
            else:
                self.ground = GroundModel(self.config.ground, self.config.max_range)

    @property
    def threshold(self) -> float:
        """The current adaptive correspondence threshold (sigma), as :class:`KissOdometry`'s."""
        return float(self.adaptive_threshold.get_threshold())

    def local_map_points(self) -> np.ndarray:
        """Points of the map (world frame = first frame), ``float64[M, 3]``."""
        return self.map.point_cloud()[0]

    def register(
        self,
        points: np.ndarray,
        times: np.ndarray | None = None,
        labels: np.ndarray | None = None,
        frame_time: float | None = None,
        source: np.ndarray | None = None,
    ) -> np.ndarray:
        """Register one frame and return its pose (4x4, world = first frame) at the frame's
        reference time.

        Parameters
        ----------
        points : float (N, 3)
            Sensor-frame points (not modified); non-finite ones are left out and counted.
        times : float (N,), optional
            Acquisition times for deskewing (the adapter's convention, see :mod:`.kiss`).
        labels : uint8 (N,), optional
            Class code per point; without labels every point is in the "other" group.
        frame_time : float, optional
            The instant the frame's pose refers to.
        source : bool (N,), optional
            The points registered (the ICP source, as :meth:`KissOdometry.register`); every
            point still goes to the map. Default: every point.

        Raises
        ------
        OdometryFailure
            Non-finite pose, pose jump beyond the guard's bounds, ICP at its iteration limit.
        """

        raw = np.asarray(points)
        if raw.ndim != 2 or raw.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got {raw.shape}")
        codes = np.full(len(raw), L.UNCLASSIFIED, np.uint8) if labels is None else np.asarray(labels, np.uint8)
        if codes.shape != (len(raw),):
            raise ValueError(f"{codes.size} labels for {len(raw)} points")
        finite = np.isfinite(raw).all(axis=1)
        if source is not None and np.shape(source) != (len(raw),):
            raise ValueError(f"source mask of shape {np.shape(source)} for {len(raw)} points")
        chosen = np.ones(int(finite.sum()), bool) if source is None else np.asarray(source, bool)[finite]
        given = (raw, times, frame_time, source, labels)  # for the prc registration to fall back on
        pts, times, dropped, t_ref, dt = self._prepare(raw, times, frame_time)
        codes = codes[finite]
        if not is_rigid(self.last_pose) or not is_rigid(self.last_delta):
            raise OdometryFailure("the odometry state is not a finite rigid transform")
        measured = pts
        pts, stamps = self._deskew(measured, times, t_ref, self.last_delta)
        group = self.group_of[codes]
        downs, source, source_group = self._group_sources(pts, stamps, chosen, group, self.last_delta)
        sigma = self.adaptive_threshold.get_threshold()
        if not np.isfinite(sigma) or sigma <= 0:
            raise OdometryFailure(f"adaptive threshold is {sigma}")
        motion = self._predicted_motion(self.last_delta)
        initial = self.last_pose @ motion
        counts = np.zeros(len(GROUP_NAMES), np.int64)
        if self.map.n and len(source) < MIN_SOURCE_POINTS:
            check_pose(initial, self.last_pose, dt, self.config.guard, "the prediction")
            if self.fallback is not None:
                self.fallback.follow(given[0], given[1], given[2], initial, update_map=False)
            self.last_pose, self.last_delta = initial, motion  # the constant velocity carries on
            self.correspondences.append(counts)
            self.iterations.append(0)
            self.anchor_ratio.append(None)
            return self._coast(len(source), initial, sigma, dropped)
        first = None
        if self._anchored(source, source_group, initial, sigma):
            first = self._icp_or_none(source, source_group, initial, sigma, dt)
        if first is not None:
            new_pose, counts, iters = first
            deskewed_with = (self.last_delta, self.clock.deskew_interval())  # the motion the frame is deskewed with
            if self._redeskew_due(labels is not None, times, initial, new_pose, source, source_group, self.map, sigma):
                kept = (pts, downs, source, source_group, deskewed_with)
                for _ in range(self.config.redeskew):
                    motion = np.linalg.inv(self.last_pose) @ new_pose
                    pts, stamps = self._deskew(measured, times, t_ref, motion, self.clock.last_interval())
                    downs, source, source_group = self._group_sources(pts, stamps, chosen, group, motion)
                    again = self._icp_or_none(source, source_group, new_pose, sigma, dt)
                    if again is None:  # not converged: the frame as registered the first time
                        pts, downs, source, source_group, deskewed_with = kept
                        break
                    new_pose, counts, iters = again
                    deskewed_with = (motion, self.clock.last_interval())
                self.redeskewed.append(len(self.poses))
            if self.classes.sweep_motion and self._deskews(times):
                delta, interval = deskewed_with
                s = (sweep_times(measured, times, source) - t_ref) / interval
                pose, v, swept, more = self._icp_sweep(source, s, source_group, new_pose, sigma, dt)
                iters += more
                velocity = se3_log(delta) + v
                if self._believable(velocity, interval):
                    delta = se3_exp(velocity)
                    pts = deskew_points(measured, times, t_ref, interval, delta)
                    downs, source, source_group = self._group_sources(pts, np.zeros(0), chosen, group, delta)
                    new_pose, counts = pose, swept
                    self.sweep_corrections.append(v)
                else:  # the frame as registered and deskewed before
                    self.sweep_rejected.append(len(self.poses))
            ground = None
            if self.ground is not None and labels is not None:
                ground = self._ground_points(pts, codes)
            new_pose = self._refine(source, source_group, initial, sigma, new_pose, ground)
            if self.fallback is not None:
                self.fallback.follow(given[0], given[1], given[2], new_pose)
            if ground is not None:
                self.ground.update(ground, new_pose)
        else:
            new_pose, iters = self._register_prc(given), -1
            check_pose(new_pose, self.last_pose, dt, self.config.guard, "KISS-ICP (class-aware fallback)")
        self._health(source, source_group, new_pose, sigma, dropped, int(iters), self.map)
        self.adaptive_threshold.update_model_deviation(np.linalg.inv(initial) @ new_pose)
        down = np.concatenate(downs)
        self.map.update(down, np.repeat(np.arange(len(GROUP_NAMES)), [len(d) for d in downs]), new_pose)
        self.last_delta = np.linalg.inv(self.last_pose) @ new_pose
        self.last_pose = new_pose
        self.poses.append(new_pose.copy())
        self.correspondences.append(counts)
        self.iterations.append(int(iters))
        return new_pose.copy()

    def _anchored(self, source: np.ndarray, source_group: np.ndarray, initial: np.ndarray, sigma: float) -> bool:
        """Whether this sweep is matched class-aware: always without ``fallback``; else when its
        anchors (:data:`ANCHOR_GROUP`), matched to the map at the predicted pose, constrain x, y
        and yaw (:data:`ANCHOR_AXES`) on their own: the smallest over the largest eigenvalue of
        their scaled information (:mod:`~prc_slam.odometry.degeneracy`, a stem's points as a line
        across which they constrain the pose) in those three directions is at least
        ``odometry.degeneracy.ratio``. Recorded in ``anchor_ratio``."""
        if self.fallback is None:
            self.anchor_ratio.append(None)
            return True
        if not self.map.n:
            self.anchor_ratio.append(None)
            return False
        sel = source_group == ANCHOR_GROUP
        ratio = 0.0
        if np.count_nonzero(sel) >= len(ANCHOR_AXES):
            H, n, arm2 = surface_information(
                source[sel], source_group[sel], self.map.index(), self.voxel, sigma, initial, lines=True
            )
            ratio = block_ratio(H, arm2, ANCHOR_AXES) if n >= len(ANCHOR_AXES) else 0.0
        self.anchor_ratio.append(ratio)
        return ratio >= self.config.degeneracy.ratio

    def _group_sources(
        self, pts: np.ndarray, stamps: np.ndarray, chosen: np.ndarray, group: np.ndarray, delta: np.ndarray
    ) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """KISS-ICP's preprocessing and voxelisation of a deskewed frame, group by group (``delta``:
        the motion for KISS-ICP's own deskewing, "kiss" convention only): the frame for the map per
        group, and the source (of the ``chosen`` points) with the group of each point."""
        from kiss_icp.voxelization import voxel_down_sample

        downs, sources, src_groups = [], [], []
        for gi in range(len(GROUP_NAMES)):
            sel = group == gi
            part, reg = pts[sel], chosen[sel]
            st = stamps[sel] if len(stamps) else stamps
            if len(part):
                # KISS-ICP's preprocessing (range crop; its own deskewing only with the "kiss"
                # convention) per group, so that the groups stay apart
                if not reg.all():
                    reg_part = self.preprocessor.preprocess(part[reg], st[reg] if len(st) else st, delta)
                part = self.preprocessor.preprocess(part, st, delta)
                if reg.all():
                    reg_part = part
            else:
                reg_part = part
            fd = voxel_down_sample(part, self.voxel * 0.5) if len(part) else np.zeros((0, 3))
            if reg_part is part:
                src = voxel_down_sample(fd, self.voxel * 1.5) if len(fd) else np.zeros((0, 3))
            elif len(reg_part):
                src = voxel_down_sample(voxel_down_sample(reg_part, self.voxel * 0.5), self.voxel * 1.5)
            else:
                src = np.zeros((0, 3))
            downs.append(fd.reshape(-1, 3))
            sources.append(src.reshape(-1, 3))
            src_groups.append(np.full(len(src), gi, dtype=np.int64))
        return downs, np.concatenate(sources), np.concatenate(src_groups)

    def _icp(
        self, source: np.ndarray, source_group: np.ndarray, guess: np.ndarray, sigma: float, dt: float
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """Class-aware ICP from ``guess``, with the guards; the pose, correspondences per group and
        iterations."""
        new_pose, iters = guess, 0
        counts = np.zeros(len(GROUP_NAMES), np.int64)
        if self.map.n and len(source):
            new_pose, counts, _, iters = icp(
                source, source_group, self.weights, *self.map.index(), self.voxel, guess, 3.0 * sigma, sigma,
                self.config.max_num_iterations, self.config.convergence_criterion, self.kinds, self.classes.min_shape,
            )  # fmt: skip
        check_pose(new_pose, self.last_pose, dt, self.config.guard, "class-aware ICP")
        if self.config.guard.fail_on_max_iterations and iters >= self.config.max_num_iterations:
            raise IcpNotConverged(f"class-aware ICP did not converge in {iters} iterations")
        return new_pose, counts, int(iters)

    def _icp_or_none(
        self, source: np.ndarray, source_group: np.ndarray, guess: np.ndarray, sigma: float, dt: float
    ) -> tuple[np.ndarray, np.ndarray, int] | None:
        """:meth:`_icp`, or None when it ends at its iteration limit and the prc registration is
        there to fall back on (the frame joins ``unconverged_frames``): a Gauss-Newton cycling
        between correspondences (a point between two stems' lines, a line and a point-to-point
        fallback) then costs the sweep its class-aware registration, not the variant its run."""
        try:
            return self._icp(source, source_group, guess, sigma, dt)
        except IcpNotConverged:
            if self.fallback is None:
                raise
            self.unconverged_frames.append(len(self.poses))
            return None

    def _deskews(self, times: np.ndarray | None) -> bool:
        """Whether the frame is deskewed by the adapter (per-point times, ``deskew``, the reference convention)."""
        c = self.config
        return c.deskew and c.deskew_convention == "reference" and times is not None and len(times) > 0

    def _believable(self, velocity: np.ndarray, interval: float) -> bool:
        """Whether a sweep's velocity (:func:`icp_sweep`'s twist per frame interval ``interval``) is
        finite and within the guard's bounds (``max_speed``, ``max_angular_rate``): a motion no
        platform makes is an ill-constrained registration, not a measurement."""
        guard = self.config.guard
        return bool(
            np.isfinite(velocity).all()
            and np.linalg.norm(velocity[:3]) <= guard.max_speed * interval
            and np.linalg.norm(velocity[3:]) <= guard.max_angular_rate * interval
        )

    def _icp_sweep(
        self, source: np.ndarray, s: np.ndarray, source_group: np.ndarray, guess: np.ndarray, sigma: float, dt: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """:func:`icp_sweep` from ``guess`` with the guards: the pose, the velocity correction,
        correspondences per group and iterations."""
        new_pose, v, iters = guess, np.zeros(6), 0
        counts = np.zeros(len(GROUP_NAMES), np.int64)
        if self.map.n and len(source):
            new_pose, v, counts, iters = icp_sweep(
                source, s, source_group, self.weights, self.kinds, self.classes.min_shape, *self.map.index(),
                self.voxel, guess, 3.0 * sigma, sigma, self.config.max_num_iterations,
                self.config.convergence_criterion, self.classes.sweep_prior,
            )  # fmt: skip
        check_pose(new_pose, self.last_pose, dt, self.config.guard, "class-aware ICP of the sweep's motion")
        if not np.isfinite(v).all():
            raise OdometryFailure("class-aware ICP of the sweep's motion gave a non-finite velocity")
        return new_pose, v, counts, int(iters)

    def _refine(
        self,
        source: np.ndarray,
        source_group: np.ndarray,
        initial: np.ndarray,
        sigma: float,
        pose: np.ndarray,
        ground: np.ndarray | None,
    ) -> np.ndarray:
        """After the class-aware ICP: the ground refinement of height, roll and pitch with the
        sweep's ``ground`` points (sensor frame), as the prc registration's, then the degeneracy
        handling. The frame joins ``classaware_frames``."""
        if ground is not None:
            pose, _, refined = self.ground.refine(ground, pose, sigma)
            if refined:
                self.ground_refined.append(len(self.poses))
        pose = orthonormal(self._condition(source, source_group, self.map, sigma, pose, initial))
        self.classaware_frames.append(len(self.poses))
        return pose

    def _register_prc(self, given: tuple) -> np.ndarray:
        """The prc variant's registration of this sweep (KISS-ICP on the same points, kept in
        step with this odometry's poses), with its conditioning and degenerate directions."""
        fb = self.fallback
        before = len(fb.degenerate_frames)
        points, times, frame_time, source, labels = given
        # with the labels, prc's ground refinement too (odometry.ground): prc's registration exactly
        pose = fb.register(points, times, labels, frame_time, source=source)
        self.conditioning.append(fb.conditioning[-1])
        self.degenerate_frames.extend(fb.degenerate_frames[before:])
        return pose


def warm_up() -> None:
    """Compile the ICP kernels on a tiny case (numba caches them on disk afterwards)."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(-5, 5, (200, 3))
    odo = ClassAwareOdometry()
    for _ in range(2):
        odo.register(pts, None, np.full(len(pts), L.BUILDING, np.uint8))
