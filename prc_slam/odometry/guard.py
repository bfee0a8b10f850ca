"""Guards and health of a running odometry: never hand KISS-ICP a non-finite number, stop a
variant whose pose is non-finite or jumps beyond a physical bound, and flag frames where the
registration looks like it is going wrong.

A failure (:class:`OdometryFailure`) stops one variant at one frame with a reason; the caller
(:func:`prc_slam.odometry.compare.run_compare`) records it and goes on with the other variants.
A *suspicious* frame is only flagged: its ICP inlier fraction, mean residual or adaptive
threshold left its running level by more than ``divergence_factor`` (without ground truth this is
how a user learns that a run went wrong, and where).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from prc_slam.util.voxels import find


class OdometryFailure(RuntimeError):
    """A variant cannot go on: non-finite pose, pose jump beyond the physical bound, or an ICP
    that did not converge. ``reason`` is a one-line explanation."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class GuardConfig(BaseModel):
    """Physical bounds of the platform and the divergence detector (same for every variant)."""

    model_config = ConfigDict(extra="forbid")

    max_speed: float = Field(70.0, gt=0, description="m/s; a faster frame-to-frame translation is a failure")
    max_angular_rate: float = Field(
        3.0, gt=0, description="rad/s; a faster frame-to-frame rotation is a failure (172 deg/s)"
    )
    fail_on_max_iterations: bool = Field(
        True, description="an ICP that ends at its iteration limit fails the variant (where the ICP reports it)"
    )
    divergence_factor: float = Field(
        3.0,
        gt=1,
        description="flag a frame whose residual/threshold exceeds (or inlier fraction falls below) "
        "its running median by this factor",
    )
    window: int = Field(20, ge=3, description="frames of the running median")
    warm_up: int = Field(5, ge=1, description="frames before the divergence detector starts")
    agreement_window: int = Field(
        10, ge=1, description="compare: frames over which the variants' relative motions are held against each other"
    )
    agreement_m: float = Field(0.5, ge=0, description="compare: variants' motions over the window may differ by this")
    agreement_share: float = Field(
        0.05, ge=0, description="... plus this share of the path (and of the angle turned) over the window"
    )
    agreement_deg: float = Field(2.0, gt=0, description="compare: ... and by this rotation (plus the share)")
    agreement_margin: float = Field(
        1.2, ge=1, description="compare: the variant whose last motion fits successive scans this much worse is suspect"
    )
    untrusted_share: float = Field(
        0.25, ge=0, le=1, description="a variant with more than this share of its frames suspicious is untrustworthy"
    )
    disagreeing_share: float = Field(
        0.5,
        ge=0,
        le=1,
        description="compare: ... as is one that disagrees with every other variant (a suspect each time) on more "
        "than this share of the frames they both registered",
    )


# ---- consistency of inputs and poses ---------------------------------------------------------


def finite_points(points: np.ndarray, times: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Drop points (and their times) with a non-finite coordinate; times that are not all finite
    are discarded (no deskewing of that frame). Returns ``(points, times, n_dropped)``."""
    ok = np.isfinite(points).all(axis=1)
    dropped = int(len(points) - ok.sum())
    if dropped:
        points = points[ok]
        times = None if times is None else np.asarray(times)[ok]
    if times is not None and not np.isfinite(times).all():
        times = None
    return points, times, dropped


def is_rigid(T: np.ndarray, tol: float = 1e-3) -> bool:
    """``T`` is a finite 4x4 rigid transform (orthonormal rotation, det +1, last row 0 0 0 1)."""
    T = np.asarray(T)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        return False
    R = T[:3, :3]
    return bool(
        np.abs(R.T @ R - np.eye(3)).max() < tol
        and abs(np.linalg.det(R) - 1.0) < tol
        and np.abs(T[3] - [0, 0, 0, 1]).max() < tol
    )


#: a pose whose rotation is further than this from orthonormal (largest entry of ``R R^T - I``) is
#: projected back onto SO(3) (:func:`orthonormal`): every product of poses adds ~1e-16, and KISS-ICP's
#: Sophus aborts the whole process (``SOPHUS_ENSURE``, "R is not orthogonal") near 1e-10; a windy
#: forest walk with a weak sweep prior got there within 150 frames
ORTHONORMAL_TOL = 1e-13


def orthonormal(T: np.ndarray) -> np.ndarray:
    """``T`` (4x4, finite) with its rotation replaced by the nearest rotation (SVD: ``U V^T``,
    det +1) once it has drifted beyond :data:`ORTHONORMAL_TOL` from orthonormal; else ``T`` itself."""
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() <= ORTHONORMAL_TOL:
        return T
    U, _, Vt = np.linalg.svd(R)
    if np.linalg.det(U @ Vt) < 0:
        U[:, -1] = -U[:, -1]
    out = np.array(T, dtype=np.float64)
    out[:3, :3] = U @ Vt
    return out


def rotation_angle(R: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def check_pose(new_pose: np.ndarray, last_pose: np.ndarray, dt: float, config: GuardConfig, what: str) -> None:
    """Raise :class:`OdometryFailure` unless ``new_pose`` is a finite rigid transform within the
    physical bounds (``max_speed``, ``max_angular_rate`` over ``dt`` seconds) of ``last_pose``."""
    if not np.isfinite(new_pose).all():
        raise OdometryFailure(f"{what} returned a non-finite pose")
    if not is_rigid(new_pose):
        raise OdometryFailure(f"{what} returned a transform that is not rigid")
    delta = np.linalg.inv(last_pose) @ new_pose
    dist = float(np.linalg.norm(delta[:3, 3]))
    angle = rotation_angle(delta[:3, :3])
    if dist > config.max_speed * dt:
        raise OdometryFailure(f"pose jump of {dist:.2f} m in {dt:.3f} s (bound {config.max_speed:g} m/s x {dt:.3f} s)")
    if angle > config.max_angular_rate * dt:
        raise OdometryFailure(
            f"pose jump of {np.degrees(angle):.1f} deg in {dt:.3f} s "
            f"(bound {np.degrees(config.max_angular_rate):.0f} deg/s x {dt:.3f} s)"
        )


# ---- residuals of a registration ---------------------------------------------------------------


#: metres taken off a voxel's distance before it is skipped (coordinates on a voxel face round
#: either way)
_FACE_MARGIN = 1e-6


@njit(cache=True, nogil=True, inline="always")
def nearest_map_point(p, g, table, coords, first, count, mpts, inv_voxel, max_d2):
    """The nearest map point of group ``g`` to ``p`` within the 27 voxels around it (KISS-ICP's
    correspondence search) and closer than ``sqrt(max_d2)``: ``(index, squared distance)``,
    ``(-1, max_d2)`` when there is none. Map layout of
    :class:`~prc_slam.odometry.group_map.GroupVoxelMap`.

    Voxels are visited in a fixed order, and one lying farther from ``p`` than the best match so
    far (or than ``sqrt(max_d2)``) is skipped without a look-up: the result is that of visiting
    all 27, at a fraction of the look-ups when the correspondence distance is below a voxel."""
    voxel = 1.0 / inv_voxel
    sx = p[0] * inv_voxel
    sy = p[1] * inv_voxel
    sz = p[2] * inv_voxel
    kx = np.int64(np.floor(sx))
    ky = np.int64(np.floor(sy))
    kz = np.int64(np.floor(sz))
    fx = sx - kx
    fy = sy - ky
    fz = sz - kz
    best, best_d2 = -1, max_d2
    for dx in range(-1, 2):
        ex = 0.0 if dx == 0 else max((fx if dx < 0 else 1.0 - fx) * voxel - _FACE_MARGIN, 0.0)
        if ex * ex >= best_d2:
            continue
        for dy in range(-1, 2):
            ey = 0.0 if dy == 0 else max((fy if dy < 0 else 1.0 - fy) * voxel - _FACE_MARGIN, 0.0)
            if ex * ex + ey * ey >= best_d2:
                continue
            for dz in range(-1, 2):
                ez = 0.0 if dz == 0 else max((fz if dz < 0 else 1.0 - fz) * voxel - _FACE_MARGIN, 0.0)
                if ex * ex + ey * ey + ez * ez >= best_d2:
                    continue
                v = find(table, coords, kx + dx, ky + dy, (kz + dz) * 8 + g)
                if v < 0:
                    continue
                for q in range(first[v], first[v] + count[v]):
                    d2 = (mpts[q, 0] - p[0]) ** 2 + (mpts[q, 1] - p[1]) ** 2 + (mpts[q, 2] - p[2]) ** 2
                    if d2 < best_d2:
                        best, best_d2 = q, d2
    return best, best_d2


@njit(cache=True, nogil=True)
def residuals(src, src_group, table, coords, first, count, mpts, inv_voxel, max_d2, T):
    """Inliers and their mean distance: each source point (sensor frame, moved by ``T``) to its
    nearest map point of its group within ``sqrt(max_d2)`` (the 27 voxels around it, the search
    of KISS-ICP's correspondences). Map layout of :class:`~prc_slam.odometry.group_map.GroupVoxelMap`.

    Returns
    -------
    inliers : int
    mean_distance : float
        NaN without inliers.
    """
    R = T[:3, :3]
    t = T[:3, 3]
    n_in = 0
    total = 0.0
    p = np.empty(3)
    for i in range(src.shape[0]):
        for k in range(3):
            p[k] = R[k, 0] * src[i, 0] + R[k, 1] * src[i, 1] + R[k, 2] * src[i, 2] + t[k]
        q, d2 = nearest_map_point(p, src_group[i], table, coords, first, count, mpts, inv_voxel, max_d2)
        if q >= 0:
            n_in += 1
            total += np.sqrt(d2)
    return n_in, (total / n_in if n_in else np.nan)


# ---- per-frame health and the divergence detector ------------------------------------------------


@dataclass
class FrameHealth:
    """One frame of one variant: ICP inliers (source points with a map point within 3 sigma at the
    final pose), their mean distance, the adaptive threshold sigma, ICP iterations (-1: not
    reported), points dropped as non-finite, and the divergence flag with its reason."""

    source_points: int = 0
    inliers: int = 0
    mean_residual_m: float = float("nan")
    threshold_m: float = float("nan")
    iterations: int = -1
    dropped_nonfinite: int = 0
    suspicious: bool = False
    why: str = ""

    @property
    def inlier_fraction(self) -> float:
        return self.inliers / self.source_points if self.source_points else float("nan")

    def as_dict(self) -> dict:
        d = asdict(self)
        d["inlier_fraction"] = self.inlier_fraction
        return d


class DivergenceMonitor:
    """Flags a frame whose mean residual or threshold jumps above ``divergence_factor`` times its
    running median over the last ``window`` frames, or whose inlier fraction falls below the
    running median divided by that factor (after ``warm_up`` frames)."""

    def __init__(self, config: GuardConfig) -> None:
        self.config = config
        self.history: dict[str, deque] = {k: deque(maxlen=config.window) for k in ("res", "thr", "frac")}

    def update(self, health: FrameHealth) -> FrameHealth:
        c = self.config
        values = {"res": health.mean_residual_m, "thr": health.threshold_m, "frac": health.inlier_fraction}
        reasons = []
        if len(self.history["res"]) >= c.warm_up:
            level = {}
            for k, h in self.history.items():
                arr = np.asarray(h, dtype=float)
                level[k] = float(np.nanmedian(arr)) if np.isfinite(arr).any() else np.nan
            if np.isfinite(values["res"]) and values["res"] > c.divergence_factor * level["res"]:
                reasons.append(f"mean residual {values['res']:.3f} m > {c.divergence_factor:g} x {level['res']:.3f} m")
            if np.isfinite(values["thr"]) and values["thr"] > c.divergence_factor * level["thr"]:
                reasons.append(f"threshold {values['thr']:.3f} m > {c.divergence_factor:g} x {level['thr']:.3f} m")
            frac = values["frac"]
            if health.source_points and (not np.isfinite(frac) or frac < level["frac"] / c.divergence_factor):
                reasons.append(f"inlier fraction {frac:.2f} < {level['frac']:.2f} / {c.divergence_factor:g}")
        for k, v in values.items():
            self.history[k].append(v)
        health.suspicious = bool(reasons)
        health.why = "; ".join(reasons)
        return health


# ---- a variant's health over the whole run ---------------------------------------------------------


@dataclass(frozen=True)
class VariantHealth:
    """Whether a variant's trajectory can be trusted: ``status`` is ``"ok"``, ``"untrustworthy"``
    or ``"failed"``; ``reason`` says why it is not ok (empty when it is)."""

    status: str
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def judge_variant(
    name: str,
    suspicious: Sequence[bool],
    frames: Mapping[str, int],
    disagreements: Mapping[str, Mapping[str, Any]],
    config: GuardConfig,
    failed: Mapping[str, Any] | None = None,
) -> VariantHealth:
    """The health of variant ``name`` over a run.

    A frame flagged suspicious is one step of a trajectory that is a chain: every later pose is
    composed with it, so wrong steps never average out. Isolated flags are what a sound run shows
    (a passing vehicle, one degenerate sweep: none on the simulated drives of the tests), so the
    variant stays ok with a few; with more than ``untrusted_share`` (a quarter) of its frames
    flagged the doubt is the rule, not the exception, and the variant is *untrustworthy* (a simulated
    VLP-16 walk read one sweep in 30: raw and prc+classaware 7.7 and 5.1 m off with 6 of 7 frames
    flagged, prc 0.05 m off with none).

    A variant that disagrees with every other variant (:mod:`~prc_slam.odometry.agreement`) on more
    than ``disagreeing_share`` (half) of the frames they both registered, and was a suspect of each
    of those disagreements (successive scans never cleared it), is untrustworthy too: nothing on
    the recording confirms its motion for most of the run. A variant that disagrees with all the
    others but was never a suspect (the others lost, successive scans side with it) stays ok.

    Parameters
    ----------
    name : the variant judged
    suspicious : per registered frame of ``name``, whether it was flagged
    frames : frames registered by every variant of the run (``name`` included)
    disagreements : ``AgreementMonitor.as_dict()``: per pair ``"a vs b"`` (sorted names) its
        ``first_frame``, ``frames`` and ``suspects``
    config : ``untrusted_share``, ``disagreeing_share``
    failed : ``{"frame", "reason"}`` of a variant that stopped
    """
    if failed is not None:
        return VariantHealth("failed", f"failed at frame {failed['frame']}: {failed['reason']}")
    reasons = []
    n, k = len(suspicious), sum(bool(s) for s in suspicious)
    if n and k > config.untrusted_share * n:
        reasons.append(f"{k} of {n} frames suspicious")
    against = _disagreeing_with_all(name, frames, disagreements, config.disagreeing_share)
    if against:
        others = " and ".join(o for o, _, _ in against)
        first = min(d["first_frame"] for _, d, _ in against)
        counts = " and ".join(f"{d['frames']} of {shared}" for _, d, shared in against)
        reasons.append(f"disagrees with {others} from frame {first} (on {counts} frames)")
    return VariantHealth("untrustworthy", ", ".join(reasons)) if reasons else VariantHealth("ok")


def _disagreeing_with_all(
    name: str, frames: Mapping[str, int], disagreements: Mapping[str, Mapping[str, Any]], share: float
) -> list[tuple[str, Mapping[str, Any], int]]:
    """``(other, disagreement, shared frames)`` for every other variant when ``name`` disagrees
    with each of them (as a suspect) on more than ``share`` of the frames on which they were held
    against each other (from the second frame both registered); empty otherwise, and when no other
    variant was held against it."""
    found = []
    for other in frames:
        shared = min(frames[name], frames[other]) - 1
        if other == name or shared < 1:
            continue
        d = disagreements.get(" vs ".join(sorted((name, other))))
        if d is None or name not in d["suspects"] or d["frames"] <= share * shared:
            return []
        found.append((other, d, shared))
    return found


def no_trust_line(health: Mapping[str, VariantHealth]) -> str | None:
    """The one line that leads the report and the console when no variant is ok (None otherwise)."""
    if not health or any(h.ok for h in health.values()):
        return None
    return "no variant can be trusted on this recording: " + "; ".join(f"{n}: {h.reason}" for n, h in health.items())
