"""Adapter around ``kiss_icp.kiss_icp.KissICP`` with the same defaults as KISS-ICP.

KISS-ICP's ``KISSConfig`` is a pydantic-settings model that reads ``kiss_icp_*`` environment
variables; the adapter builds it with every section given explicitly and those variables
hidden, so runs do not depend on the caller's shell. ``voxel_size`` defaults to
``max_range / 100`` as in KISS-ICP's own ``load_config``.

Time convention. KISS-ICP's own deskewing normalises the stamps it is given
to [0, 1] over the points' min and max and moves every point to the instant of the *last* point
(``exp((s - 1) log(delta))``), so its pose is the pose at the end of the points' time span,
and a sweep whose points cover part of the period (a sector, a filtered frame) is stretched
over a whole frame of motion. Our datasets give each frame's pose at the frame's *reference
time* (``scan.meta["frame_time"]``: the simulator's mid-sweep, KITTI's ``times.txt``). The
adapter therefore deskews itself (:func:`deskew_points`), with the constant-velocity model of
KISS-ICP: point ``i`` at time ``t_i`` is moved by ``exp(((t_i - t_ref) / dt) log(delta))``,
``delta`` being the motion between the last two frames and ``dt`` the time between their
reference instants; the deskewed frame goes to KISS-ICP without stamps. The returned pose is the
pose at ``t_ref``, whatever the spin direction, the sweep's start or the points' time span.
``deskew_convention="kiss"`` keeps KISS-ICP's own (end of the span) behaviour for comparison.

Deskewing again (``redeskew``). The constant-velocity model is KISS-ICP's prediction of the
frame's motion; a walker's step bounce (2 Hz, pitch and height) or a handheld sensor's sway
changes the velocity within a few sweeps, and the frame is then registered distorted. For the
frames given labels, a registration that departs from the prediction by more than half a voxel
(KISS-ICP's model error, :func:`model_error`) is followed by deskewing the frame again with the
motion just registered (previous pose to this one) and registering it again from there, as
continuous-time odometry refines a sweep's motion with its registration (CT-ICP, Dellenbach et
al., ICRA 2022, does so jointly). Measured on a simulated forest walk (vlp16, 300 frames,
``scripts/odometry_acceptance.py --only forest``): prc ATE 0.094 -> 0.038 m; urban drives at
constant speed deskew again only their first frames from rest.
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from typing import Literal

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from prc_slam import labels as L
from prc_slam.odometry.degeneracy import Conditioning, DegeneracyConfig, analyse
from prc_slam.odometry.ground import GroundConfig, GroundModel, ground_points
from prc_slam.odometry.group_map import GroupVoxelMap
from prc_slam.odometry.guard import (
    DivergenceMonitor,
    FrameHealth,
    GuardConfig,
    OdometryFailure,
    check_pose,
    finite_points,
    is_rigid,
    orthonormal,
    residuals,
)


class OdometryConfig(BaseModel):
    """KISS-ICP parameters (KISS-ICP 1.x defaults)."""

    model_config = ConfigDict(extra="forbid")

    max_range: float = Field(100.0, gt=0)
    min_range: float = Field(0.0, ge=0)
    deskew: bool = True
    voxel_size: float | None = Field(None, gt=0, description="default: max_range / 100")
    max_points_per_voxel: int = Field(20, ge=1)
    initial_threshold: float = Field(2.0, gt=0)
    min_motion_th: float = Field(0.1, ge=0)
    max_num_iterations: int = Field(500, ge=1)
    convergence_criterion: float = Field(1e-4, gt=0)
    max_num_threads: int = Field(
        0,
        ge=0,
        description="KISS-ICP's threads; 0: automatic (every core, or PRC_SLAM_THREADS when set, as `batch` does "
        "for its local workers so that they share the cores)",
    )
    deskew_convention: Literal["reference", "kiss"] = Field(
        "reference",
        description="reference: poses at each frame's reference time, deskewed by the adapter with the real "
        "per-point times; kiss: KISS-ICP's own deskewing (stamps normalised over the frame, pose at the last point)",
    )
    overlap: bool = Field(
        True,
        description="in compare and odometry runs: read, organise and classify the next frame on a second thread "
        "while the PRC variants filter and register this one (variants without PRC register alone); a PRC "
        "variant is charged the wall time",
    )
    overlap_process: bool = Field(
        True,
        description="with overlap: make the next frame in a forked second process where that is safe (POSIX, "
        "numba's threads not yet started) instead of a thread, whose Python steps wait for the GIL that "
        "KISS-ICP holds while it registers",
    )
    guard: GuardConfig = Field(default_factory=GuardConfig)
    degeneracy: DegeneracyConfig = Field(default_factory=DegeneracyConfig)
    ground: GroundConfig = Field(default_factory=GroundConfig)
    redeskew: int = Field(
        1,
        ge=0,
        description="variants with labels: when a frame's registration departs from the constant-velocity "
        "prediction so far that its deskewing error at the sweep's ends exceeds a quarter voxel (KISS-ICP's model "
        "error over half a voxel), deskew it again with the motion just registered and register it again, this "
        "many times (0: KISS-ICP's single pass with the prediction); redeskewed_frames in the metrics",
    )


def model_error(deviation: np.ndarray, max_range: float) -> float:
    """KISS-ICP's model error of a deviation from the prediction (Vizzo et al., RA-L 2023, Sec.
    III-C, eq. 7): its translation plus the displacement ``2 r_max sin(theta / 2)`` its rotation
    gives a point at the maximum range."""
    cos = np.clip((np.trace(deviation[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos))
    return float(np.linalg.norm(deviation[:3, 3])) + 2.0 * max_range * np.sin(theta / 2.0)


@contextmanager
def _without_kiss_env():
    saved = {k: os.environ.pop(k) for k in [k for k in os.environ if k.lower().startswith("kiss_icp_")]}
    try:
        yield
    finally:
        os.environ.update(saved)


def _threads_from_env() -> int:
    """``PRC_SLAM_THREADS`` (a positive integer), else 0 (KISS-ICP's own choice: every core)."""
    value = os.environ.get("PRC_SLAM_THREADS", "")
    return int(value) if value.isdigit() and int(value) > 0 else 0


def kiss_config(config: OdometryConfig):
    """The ``KISSConfig`` for ``config``, independent of ``kiss_icp_*`` environment variables."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig

    with _without_kiss_env():
        return KISSConfig(
            out_dir="/dev/null",
            data=DataConfig(max_range=config.max_range, min_range=config.min_range, deskew=config.deskew),
            mapping=MappingConfig(
                voxel_size=config.voxel_size if config.voxel_size is not None else config.max_range / 100.0,
                max_points_per_voxel=config.max_points_per_voxel,
            ),
            registration=RegistrationConfig(
                max_num_iterations=config.max_num_iterations,
                convergence_criterion=config.convergence_criterion,
                max_num_threads=config.max_num_threads or _threads_from_env(),
            ),
            adaptive_threshold=AdaptiveThresholdConfig(
                initial_threshold=config.initial_threshold, min_motion_th=config.min_motion_th
            ),
        )


def deskew_stamps(times: np.ndarray | None, n: int) -> np.ndarray:
    """Per-point times normalised to [0, 1] over the frame for KISS-ICP's own deskewing (its
    ``deskew_convention="kiss"``); an empty array (KISS-ICP's "do not deskew") without times for
    every point."""
    if times is None or len(times) != n or n == 0:
        return np.zeros(0)
    t = np.asarray(times, dtype=np.float64)
    span = float(t.max() - t.min())
    return (t - t.min()) / span if span > 0 else np.full(n, 0.5)


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twist ``(rho, omega)`` (translation first, as Sophus) of a rigid 4x4 transform."""
    R, t = T[:3, :3], T[:3, 3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos))
    vee = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-8:
        w = 0.5 * vee
    elif np.pi - theta < 1e-6:  # near pi: the axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(R) + 1.0) / 2.0, 0.0))
        axis *= np.where(vee >= 0, 1.0, -1.0)
        w = theta * axis / max(np.linalg.norm(axis), 1e-12)
    else:
        w = theta / (2.0 * np.sin(theta)) * vee
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-8:
        V_inv = np.eye(3) - 0.5 * K
    else:
        V_inv = np.eye(3) - 0.5 * K + (1.0 / theta**2) * (1.0 - theta * np.sin(theta) / (2.0 * (1.0 - cos))) * (K @ K)
    return np.concatenate([V_inv @ t, w])


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """The rigid 4x4 transform of the twist ``xi = (rho, omega)`` (inverse of :func:`se3_log`)."""
    rho, w = np.asarray(xi[:3], dtype=np.float64), np.asarray(xi[3:], dtype=np.float64)
    th2 = float(w @ w)
    if th2 < 1e-16:
        a, b, c = 1.0, 0.5, 1.0 / 6.0
    else:
        th = np.sqrt(th2)
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
        c = (1.0 - a) / th2
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + a * K + b * (K @ K)
    T[:3, 3] = (np.eye(3) + b * K + c * (K @ K)) @ rho
    return T


@njit(cache=True, nogil=True)
def _deskew_kernel(points, s, xi):
    """``exp(s_i xi) p_i`` for every point (Rodrigues and the SE(3) left Jacobian, scalar code)."""
    n = points.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        si = s[i]
        rx, ry, rz = si * xi[0], si * xi[1], si * xi[2]
        wx, wy, wz = si * xi[3], si * xi[4], si * xi[5]
        th2 = wx * wx + wy * wy + wz * wz
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        if th2 < 1e-16:
            a, b, c = 1.0, 0.5, 1.0 / 6.0
        else:
            th = np.sqrt(th2)
            a = np.sin(th) / th
            b = (1.0 - np.cos(th)) / th2
            c = (1.0 - a) / th2
        # R p = p + a (w x p) + b w x (w x p)
        cx, cy, cz = wy * pz - wz * py, wz * px - wx * pz, wx * py - wy * px
        ccx, ccy, ccz = wy * cz - wz * cy, wz * cx - wx * cz, wx * cy - wy * cx
        # V rho = rho + b (w x rho) + c w x (w x rho)
        dx, dy, dz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
        ddx, ddy, ddz = wy * dz - wz * dy, wz * dx - wx * dz, wx * dy - wy * dx
        out[i, 0] = px + a * cx + b * ccx + rx + b * dx + c * ddx
        out[i, 1] = py + a * cy + b * ccy + ry + b * dy + c * ddy
        out[i, 2] = pz + a * cz + b * ccz + rz + b * dz + c * ddz
    return out


def deskew_points(points: np.ndarray, times: np.ndarray, t_ref: float, dt: float, delta: np.ndarray) -> np.ndarray:
    """Motion-compensate a frame to its reference instant with a constant velocity.

    Parameters
    ----------
    points : float (N, 3)
        Sensor-frame points, each measured at ``times[i]`` (s).
    t_ref : float
        The instant the frame's pose refers to.
    dt : float
        Seconds over which the sensor moved by ``delta``.
    delta : float (4, 4)
        Relative motion over ``dt`` (the previous frame's pose to this one's, in the previous
        sensor frame), the constant-velocity model of KISS-ICP.

    Returns
    -------
    float (N, 3)
        ``exp(((t_i - t_ref) / dt) log(delta)) p_i``: every point in the sensor frame at ``t_ref``.
    """
    s = (np.asarray(times, dtype=np.float64) - t_ref) / dt
    return _deskew_kernel(np.ascontiguousarray(points, dtype=np.float64), s, se3_log(delta))


#: fewer correspondences than this at the initial guess: the frame cannot be registered
MIN_CORRESPONDENCES = 6
#: a frame with fewer ICP source points than this (after voxelising) is not registered: its pose is
#: the constant-velocity prediction, the map is left as it was, and the frame is flagged and counted
#: (a sweep cut short, or one whose points a filter removed); six unknowns need far more points
MIN_SOURCE_POINTS = 30


#: the constant-velocity prediction is stretched to the time since the previous frame once that
#: interval differs from the one the last motion was observed over by more than this factor (frames
#: dropped, a rate change); within it the stamps' jitter is noise, and the frame-to-frame motion is
#: predicted as KISS-ICP does. KITTI 00 without its frames 5-11 (a 0.8 s gap at 8.6 m/s): the PRC
#: variants predicted 0.9 m instead of 6.9 m and locked 5 m short (ATE 2.9 m, raw 0.45 m).
PREDICTION_RESCALE = 1.5


class FrameClock:
    """Reference time and deskewing interval of successive frames.

    The reference time is the frame's own (``frame_time``), else the middle of its points' time
    span, else the previous one plus the last interval (0.1 s at first, said in ``assumed``). The
    deskew interval is the time between the last two reference instants, the interval over which
    the constant-velocity ``delta`` was observed."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self.assumed = False

    def next(self, frame_time: float | None, times: np.ndarray | None) -> float:
        if frame_time is not None and np.isfinite(frame_time):
            t = float(frame_time)
        elif times is not None and len(times):
            t = 0.5 * (float(np.min(times)) + float(np.max(times)))
        else:
            self.assumed = True
            t = self.times[-1] + self.last_interval() if self.times else 0.0
        if self.times and t <= self.times[-1]:
            raise OdometryFailure(f"frame time {t:.6f} s does not follow the previous {self.times[-1]:.6f} s")
        self.times.append(t)
        return t

    def last_interval(self) -> float:
        """Seconds between the last two frames (0.1 s before there are two)."""
        return self.times[-1] - self.times[-2] if len(self.times) >= 2 else 0.1

    def deskew_interval(self) -> float:
        """Seconds between the two frames before the newest one (the interval of ``delta``)."""
        return self.times[-2] - self.times[-3] if len(self.times) >= 3 else self.last_interval()


class GuardedOdometry:
    """What both odometries share: checked inputs, the frame clock, the adapter's deskewing and
    the per-frame health (:mod:`prc_slam.odometry.guard`)."""

    config: OdometryConfig

    def _init_guard(self) -> None:
        self.poses: list[np.ndarray] = []
        self.health: list[FrameHealth] = []
        self.health_ms: list[float] = []
        self.clock = FrameClock()
        self.monitor = DivergenceMonitor(self.config.guard)
        self._pending_ms = 0.0  # guard time spent before the health of the frame is recorded
        self.coasted: list[int] = []  # frames (indices into poses) given the predicted pose, not registered
        #: the ``time.perf_counter()`` intervals of the last frame's health work (not registration)
        self.health_spans: list[tuple[float, float]] = []
        #: per registered frame, its conditioning (None: not registered against a map, or not computed)
        self.conditioning: list[Conditioning | None] = []
        #: frames (indices into poses) deskewed again with their registered motion (``redeskew``)
        self.redeskewed: list[int] = []
        #: ``{"frame", "kind", "direction", "ratio", "kept_prediction"}`` per degenerate direction of a frame
        self.degenerate_frames: list[dict] = []

    def _health_since(self, t0: float) -> float:
        """Record the health work from ``t0`` until now; its milliseconds."""
        t1 = time.perf_counter()
        self.health_spans.append((t0, t1))
        return (t1 - t0) * 1e3

    def _prepare(
        self, points: np.ndarray, times: np.ndarray | None, frame_time: float | None
    ) -> tuple[np.ndarray, np.ndarray | None, int, float, float]:
        """Checked, finite points and times; the frame's reference time and the pose-jump interval."""
        self.health_spans = []
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got {pts.shape}")
        if times is not None and np.shape(times) != (len(pts),):
            times = None
        pts, times, dropped = finite_points(pts, times)
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        t_ref = self.clock.next(frame_time, times)
        if times is not None and len(times):
            lo, hi = float(np.min(times)), float(np.max(times))
            far = max(abs(lo - t_ref), abs(hi - t_ref))
            if far > max(10.0, 10.0 * (hi - lo), 10.0 * self.clock.last_interval()):
                raise OdometryFailure(
                    f"the points' times lie {far:.4g} s from the frame's time {t_ref:.6f} s: not on one clock "
                    "(check the reader's time field, or give the frames' times)"
                )
        return pts, times, dropped, t_ref, self.clock.last_interval()

    def _deskew(self, pts, times, t_ref, last_delta, interval=None):
        """Deskewed points and the stamps to give KISS-ICP's preprocessor (empty: none);
        ``last_delta`` is the motion over ``interval`` (default: the clock's deskew interval)."""
        if not self.config.deskew or times is None or len(pts) == 0:
            return pts, np.zeros(0)
        if self.config.deskew_convention == "kiss":
            return pts, deskew_stamps(times, len(pts))
        if not is_rigid(last_delta):
            raise OdometryFailure("the constant-velocity motion is not a finite rigid transform")
        dt = self.clock.deskew_interval() if interval is None else interval
        return deskew_points(pts, times, t_ref, dt, last_delta), np.zeros(0)

    def _redeskew_due(self, labelled: bool, times, initial: np.ndarray, pose: np.ndarray, source, groups, gmap,
                      sigma: float) -> bool:  # fmt: skip
        """Whether to deskew the frame again with its registered motion (``redeskew``).

        KISS-ICP deskews a frame with the constant-velocity prediction. When the registration
        departs from it by a model error ``e`` (:func:`model_error`), the points at the sweep's ends
        were deskewed wrong by up to ``e / 2``. Beyond a quarter voxel (``e`` over half a voxel)
        that moves points across the cells of the frame's downsampling (half a voxel) and distorts
        what is registered and mapped: the frame is deskewed again with the motion just registered
        and registered again. For frames given labels (the PRC variants; without labels the
        odometry is KISS-ICP's) with per-point times. Measured (model error, 120 frames, 1 m voxel):
        an urban hdl64 drive at 0.10-0.45 m (p10-p99) never crosses it; a walker in a forest (2 Hz
        step bounce and pitch, 1 Hz roll and yaw) at 1.8-7.3 m always does.

        Not when the registration is degenerate (after the guard's warm-up, with
        ``degeneracy.enabled``; :mod:`~prc_slam.odometry.degeneracy` of ``source`` on ``gmap`` at
        ``pose``): along a featureless corridor the registration slides along the axis, its
        departure from the prediction is that slide, not the motion, and deskewing with it carries
        the slide into the frame. Measured on the simulated road tunnel (hdl64, seed 0, prc): ATE
        0.63 m without deskewing again, 3.04 m deskewing again every departing frame (176), 1.13 m
        with this rule (79 frames; near-degenerate frames still slide).
        """
        if not (labelled and self.config.redeskew and self.config.deskew and times is not None and len(times)):
            return False
        if model_error(np.linalg.inv(initial) @ pose, self.config.max_range) <= 0.5 * self.voxel:
            return False
        cfg = self.config.degeneracy
        if cfg.enabled and gmap.n and len(source) and len(self.poses) >= self.config.guard.warm_up:
            return not analyse(source, groups, gmap.index(), gmap.voxel, sigma, pose, cfg.ratio).degenerate
        return True

    def _ground_points(self, pts: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """The frame's points the ground refinement matches (:mod:`~prc_slam.odometry.ground`): labelled
        ground within both its range and the odometry's."""
        g = self.config.ground
        return ground_points(pts, labels, [L.GROUND], self.config.min_range, min(g.max_range, self.config.max_range))

    def _predicted_motion(self, last_delta: np.ndarray) -> np.ndarray:
        """The motion expected from the previous frame to this one at constant velocity:
        ``last_delta`` (observed over :meth:`FrameClock.deskew_interval`), stretched to the time
        since the previous frame when the two intervals differ by more than
        :data:`PREDICTION_RESCALE`."""
        ratio = self.clock.last_interval() / self.clock.deskew_interval()
        if 1.0 / PREDICTION_RESCALE <= ratio <= PREDICTION_RESCALE:
            return last_delta
        return se3_exp(ratio * se3_log(last_delta))

    def _coast(self, n_source: int, predicted: np.ndarray, sigma: float, dropped: int) -> np.ndarray:
        """Give the frame the predicted pose without registering it (:data:`MIN_SOURCE_POINTS`)."""
        why = f"only {n_source} ICP source points: pose predicted at constant velocity, map not updated"
        h = FrameHealth(source_points=n_source, threshold_m=float(sigma), dropped_nonfinite=dropped, suspicious=True,
                        why=why)  # fmt: skip
        self.health.append(h)
        self.health_ms.append(self._pending_ms)
        self._pending_ms = 0.0
        self.coasted.append(len(self.poses))
        self.conditioning.append(None)
        self.poses.append(predicted.copy())
        return predicted.copy()

    def _health(self, source, groups, pose, sigma, dropped, iterations, gmap) -> FrameHealth:
        t0 = time.perf_counter()
        h = FrameHealth(source_points=len(source), threshold_m=float(sigma), iterations=iterations,
                        dropped_nonfinite=dropped)  # fmt: skip
        if gmap.n and len(source):
            h.inliers, h.mean_residual_m = residuals(
                source, groups, *gmap.index(), 1.0 / gmap.voxel, (3.0 * sigma) ** 2, pose
            )  # fmt: skip
        else:
            h.inliers, h.source_points = 0, 0  # no map yet: nothing to judge
        self.monitor.update(h)
        self.health.append(h)
        self.health_ms.append(self._health_since(t0) + self._pending_ms)
        self._pending_ms = 0.0
        return h

    def _condition(self, source, groups, gmap, sigma, pose, initial) -> np.ndarray:
        """The frame's conditioning at ``pose`` (:mod:`~prc_slam.odometry.degeneracy`), recorded;
        after the guard's warm-up frames, degenerate directions are recorded in
        ``degenerate_frames`` and the pose returned keeps ``initial`` (the constant-velocity
        prediction) along them when ``degeneracy.keep_prediction`` says so (else ``pose``)."""
        cfg = self.config.degeneracy
        if not cfg.enabled or not gmap.n or not len(source):
            self.conditioning.append(None)
            return pose
        cond = analyse(source, groups, gmap.index(), gmap.voxel, sigma, pose, cfg.ratio)
        self.conditioning.append(cond)
        frame = len(self.poses)
        if not cond.degenerate or frame < self.config.guard.warm_up:
            # a map of the first few sweeps holds too few points a voxel to show its surfaces, and
            # the constant velocity is not yet known: the guard's warm-up frames are not judged
            return pose
        keep = cfg.keep_prediction
        for d in cond.directions():
            self.degenerate_frames.append({"frame": frame, **d, "kept_prediction": keep})
        if not keep:
            return pose
        xi = cond.project(se3_log(np.linalg.inv(initial) @ pose))
        return initial @ se3_exp(xi)


class KissOdometry(GuardedOdometry):
    """Frame-to-map odometry with KISS-ICP; poses start at the identity.

    KISS-ICP's steps (``KissICP.register_frame``: preprocess, voxelise, register, update
    threshold and map) with the adapter's deskewing (module docstring), guards before anything
    reaches KISS-ICP's C++ (which aborts the process on a NaN) and after (non-finite pose, pose
    jump beyond :class:`~prc_slam.odometry.guard.GuardConfig`'s bounds: :class:`OdometryFailure`,
    the state left as before the frame), and the frame's health (ICP inliers and mean residual
    at the final pose on a shadow copy of the voxel map, threshold, divergence flag). With
    labels (the PRC variants) two steps beyond KISS-ICP follow the registration: deskewing again
    with the registered motion (module docstring) and the ground refinement
    (:mod:`~prc_slam.odometry.ground`); without labels the registration is KISS-ICP's own.

    Parameters
    ----------
    config : OdometryConfig
    """

    name = "KISS-ICP"

    def __init__(self, config: OdometryConfig | None = None) -> None:
        from kiss_icp.kiss_icp import KissICP

        self.config = config or OdometryConfig()
        self.kiss = KissICP(kiss_config(self.config))
        self.voxel = self.kiss.config.mapping.voxel_size
        self._init_guard()
        self._shadow = None
        self.deskewed = np.zeros((0, 3))
        self.ground = GroundModel(self.config.ground, self.config.max_range) if self.config.ground.enabled else None
        #: per frame given labels, the ground points matched by the ground refinement
        self.ground_matches: list[int] = []
        #: frames (indices into poses) whose height, roll and pitch the ground refinement moved
        #: (fewer than ``ground.min_matches`` matches, e.g. rough or unlabelled ground, leave a frame as registered)
        self.ground_refined: list[int] = []

    # ---- KISS-ICP ----

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
            Sensor-frame points, not modified. Points with a non-finite coordinate are left out
            (counted in the frame's health).
        times : float (N,), optional
            Acquisition time per point (s), for deskewing. Without times (or with ``deskew``
            off) the frame is not deskewed.
        labels : uint8 (N,), optional
            One code per point; with ``ground.enabled``, the ground points refine the registered
            pose's height, roll and pitch (:mod:`~prc_slam.odometry.ground`). Otherwise ignored.
        frame_time : float, optional
            The instant the frame's pose refers to (s, the clock of ``times``); default: the
            middle of the points' time span.
        source : bool (N,), optional
            The points KISS-ICP registers (its source, voxelised by KISS-ICP at 1.5 voxel sizes
            as usual); all points still go to the map (voxelised at 0.5 voxel sizes). Default:
            every point, which is KISS-ICP's own ``register_frame``.

        Raises
        ------
        OdometryFailure
            Non-finite pose, pose jump beyond the guard's bounds, or non-monotonic frame times.
        """
        kiss = self.kiss
        if source is not None:
            source = np.asarray(source, dtype=bool)
            if source.shape != (len(points),):
                raise ValueError(f"source mask of shape {source.shape} for {len(points)} points")
            source = source[np.isfinite(np.asarray(points)).all(axis=1)]
        labelled = labels is not None
        if self.ground is not None and labels is not None:
            labels = np.asarray(labels)
            if labels.shape != (len(points),):
                raise ValueError(f"labels of shape {labels.shape} for {len(points)} points")
            labels = labels[np.isfinite(np.asarray(points)).all(axis=1)]
        else:
            labels = None
        pts, times, dropped, t_ref, dt = self._prepare(points, times, frame_time)
        if not is_rigid(kiss.last_pose) or not is_rigid(kiss.last_delta):
            raise OdometryFailure("the odometry state is not a finite rigid transform")
        measured = pts
        pts, stamps = self._deskew(measured, times, t_ref, kiss.last_delta)
        self.deskewed = pts  # the frame as registered (sensor frame at the reference time)
        chosen = source
        source, frame_downsample = self._voxelize(pts, stamps, chosen, kiss.last_delta)
        sigma = kiss.adaptive_threshold.get_threshold()
        motion = self._predicted_motion(kiss.last_delta)
        initial_guess = kiss.last_pose @ motion
        if not np.isfinite(sigma) or sigma <= 0:
            raise OdometryFailure(f"adaptive threshold is {sigma}")
        if self._shadow is None:
            self._shadow = GroupVoxelMap(self.voxel, self.config.max_range, self.config.max_points_per_voxel)
        if self._shadow.n and len(source) < MIN_SOURCE_POINTS:
            check_pose(initial_guess, kiss.last_pose, dt, self.config.guard, "the prediction")
            kiss.last_pose, kiss.last_delta = initial_guess, motion  # the constant velocity carries on
            return self._coast(len(source), initial_guess, sigma, dropped)
        self._check_correspondences(source, initial_guess, sigma)
        new_pose = self._align(source, initial_guess, sigma)
        check_pose(new_pose, kiss.last_pose, dt, self.config.guard, "KISS-ICP")
        groups = np.zeros(len(source), np.int64)
        if self._redeskew_due(labelled, times, initial_guess, new_pose, source, groups, self._shadow, sigma):
            for _ in range(self.config.redeskew):
                motion = np.linalg.inv(kiss.last_pose) @ new_pose
                pts, stamps = self._deskew(measured, times, t_ref, motion, self.clock.last_interval())
                source, frame_downsample = self._voxelize(pts, stamps, chosen, motion)
                new_pose = self._align(source, new_pose, sigma)
                check_pose(new_pose, kiss.last_pose, dt, self.config.guard, "KISS-ICP (deskewed again)")
            self.redeskewed.append(len(self.poses))
            self.deskewed = pts
        ground = None
        if labels is not None:
            ground = self._ground_points(pts, labels)
            new_pose, matched, refined = self.ground.refine(ground, new_pose, sigma)
            self.ground_matches.append(int(matched))
            if refined:
                self.ground_refined.append(len(self.poses))
        groups = np.zeros(len(source), np.int64)
        new_pose = orthonormal(self._condition(source, groups, self._shadow, sigma, new_pose, initial_guess))
        self._health(source, groups, new_pose, sigma, dropped, -1, self._shadow)
        kiss.adaptive_threshold.update_model_deviation(np.linalg.inv(initial_guess) @ new_pose)
        kiss.local_map.update(frame_downsample, new_pose)
        if ground is not None:
            self.ground.update(ground, new_pose)
        t0 = time.perf_counter()
        self._shadow.update(frame_downsample, np.zeros(len(frame_downsample), np.int64), new_pose)
        self.health_ms[-1] += self._health_since(t0)
        kiss.last_delta = np.linalg.inv(kiss.last_pose) @ new_pose
        kiss.last_pose = new_pose
        pose = new_pose.copy()
        self.poses.append(pose)
        return pose.copy()

    def _voxelize(self, pts, stamps, chosen, delta) -> tuple[np.ndarray, np.ndarray]:
        """KISS-ICP's preprocessing and voxelisation of a deskewed frame: the source (of the
        ``chosen`` points only, when given) and the frame for the map."""
        kiss = self.kiss
        frame = kiss.preprocessor.preprocess(pts, stamps, delta)
        if chosen is None or chosen.all():
            return kiss.voxelize(frame)
        from kiss_icp.voxelization import voxel_down_sample

        frame_downsample = voxel_down_sample(frame, self.voxel * 0.5)
        chosen_stamps = stamps[chosen] if len(stamps) else stamps
        part = kiss.preprocessor.preprocess(pts[chosen], chosen_stamps, delta)
        return (kiss.voxelize(part)[0] if len(part) else np.zeros((0, 3))), frame_downsample

    def _align(self, source: np.ndarray, guess: np.ndarray, sigma: float) -> np.ndarray:
        """KISS-ICP's registration of ``source`` to its map from ``guess``."""
        kiss = self.kiss
        return np.asarray(
            kiss.registration.align_points_to_map(
                points=source,
                voxel_map=kiss.local_map,
                initial_guess=guess,
                max_correspondance_distance=3 * sigma,
                kernel=sigma,
            )
        )

    def follow(
        self,
        points: np.ndarray,
        times: np.ndarray | None,
        frame_time: float | None,
        pose: np.ndarray,
        update_map: bool = True,
    ) -> None:
        """Take ``pose`` as this frame's pose without registering it: the map (unless
        ``update_map`` is False), the adaptive threshold and the constant-velocity model go on from
        it, as after :meth:`register`. For an odometry that registered the frame otherwise
        (:class:`~prc_slam.odometry.classaware.ClassAwareOdometry` with its anchors) and keeps
        this one in step to fall back on. The ground model (``ground.enabled``) is not updated
        here: the class-aware odometry shares it, and refines and updates it itself."""
        from kiss_icp.voxelization import voxel_down_sample

        kiss = self.kiss
        pts, times, _, t_ref, _ = self._prepare(points, times, frame_time)
        pts, stamps = self._deskew(pts, times, t_ref, kiss.last_delta)
        initial = kiss.last_pose @ self._predicted_motion(kiss.last_delta)
        if update_map:
            frame = kiss.preprocessor.preprocess(pts, stamps, kiss.last_delta)
            down = voxel_down_sample(frame, self.voxel * 0.5) if len(frame) else np.zeros((0, 3))
            kiss.adaptive_threshold.update_model_deviation(np.linalg.inv(initial) @ pose)
            kiss.local_map.update(down, pose)
            if self._shadow is None:
                self._shadow = GroupVoxelMap(self.voxel, self.config.max_range, self.config.max_points_per_voxel)
            self._shadow.update(down, np.zeros(len(down), np.int64), pose)
        kiss.last_delta = np.linalg.inv(kiss.last_pose) @ pose
        kiss.last_pose = np.array(pose, dtype=np.float64)
        self.conditioning.append(None)
        self.poses.append(self.kiss.last_pose.copy())

    def _check_correspondences(self, source: np.ndarray, guess: np.ndarray, sigma: float) -> None:
        """KISS-ICP solves its normal equations without a rank check, and a NaN from them aborts
        the process (``SOPHUS_ENSURE``): with a map, refuse a source that has fewer than
        ``MIN_CORRESPONDENCES`` map points within 3 sigma at the initial guess."""
        if not self._shadow.n:
            return
        t0 = time.perf_counter()
        n, _ = residuals(
            source, np.zeros(len(source), np.int64), *self._shadow.index(), 1.0 / self.voxel, (3.0 * sigma) ** 2, guess
        )  # fmt: skip
        self._pending_ms = self._health_since(t0)
        if n < MIN_CORRESPONDENCES:
            raise OdometryFailure(
                f"only {n} of {len(source)} source points have a map point within 3 sigma ({3 * sigma:.2f} m) "
                "of the predicted pose: registration impossible"
            )

    def local_map_points(self) -> np.ndarray:
        """Points of KISS-ICP's voxel map (world frame = first frame), ``float64[M, 3]``."""
        return np.asarray(self.kiss.local_map.point_cloud())

    @property
    def threshold(self) -> float:
        """KISS-ICP's current adaptive correspondence threshold (sigma)."""
        return float(self.kiss.adaptive_threshold.get_threshold())


__all__ = ["GuardConfig", "KissOdometry", "OdometryConfig", "OdometryFailure", "deskew_points", "kiss_config"]
