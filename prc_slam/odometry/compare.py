"""Run odometry variants side by side in one process over the same frames.

Variants: ``raw`` (every point to KISS-ICP), ``prc`` (PRC labels, then the filter policy of
:mod:`prc_slam.filtering`, then KISS-ICP with the same settings) and ``prc+classaware`` (the
same filtered points with their labels to :class:`~prc_slam.odometry.classaware.ClassAwareOdometry`).
Each frame is read once and given to every variant in turn, so machine noise hits all variants
alike.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from prc_slam import labels as L
from prc_slam.config import Config
from prc_slam.evaluation import metrics as E
from prc_slam.filtering import filter_points
from prc_slam.odometry import classaware
from prc_slam.odometry.agreement import AgreementMonitor
from prc_slam.odometry.classaware import GROUP_NAMES, ClassAwareOdometry
from prc_slam.odometry.guard import GuardConfig, VariantHealth, judge_variant, no_trust_line
from prc_slam.odometry.kiss import KissOdometry
from prc_slam.pipeline import ClassifiedFrame, NextFrame, ReadAhead, classify_frames, unclassified
from prc_slam.prc.algorithm import warm_up
from prc_slam.scan import Scan

#: peer variants: a filter of another method before the same KISS-ICP settings
PEER_VARIANTS = ("sor", "ror", "patchwork")
#: the variants that filter with PRC's labels
PRC_VARIANTS = ("prc", "prc+classaware")
VARIANTS = ("raw", *PRC_VARIANTS, *PEER_VARIANTS)
DEFAULT_VARIANTS = ("raw", "prc")


#: stages timed per frame; ``health`` (the guard's residuals on a shadow map) is reported apart
#: and not counted in ``ms_per_frame`` (it is monitoring, the same for every variant)
STAGES = ("prc", "filter", "icp")


@dataclass
class VariantRun:
    """Per-frame record of one variant. ``failed`` is ``{"frame", "reason"}`` once the variant
    has stopped (its poses, times and counts cover the frames before)."""

    name: str
    odometry: KissOdometry | ClassAwareOdometry
    ms: dict[str, list[float]] = field(default_factory=lambda: {k: [] for k in STAGES})
    #: per frame, the milliseconds of the stages that ran beside others (the next frame's PRC
    #: beside this frame's filter and registration), subtracted from their sum
    hidden: list[float] = field(default_factory=list)
    points_in: list[int] = field(default_factory=list)
    points_to_icp: list[int] = field(default_factory=list)
    counts_in: dict[str, int] = field(default_factory=dict)
    counts_kept: dict[str, int] = field(default_factory=dict)
    failed: dict[str, Any] | None = None

    @property
    def poses(self) -> np.ndarray:
        return np.array(self.odometry.poses).reshape(-1, 4, 4)

    @property
    def frames(self) -> int:
        return len(self.odometry.poses)

    def ms_per_frame(self, serial: bool = False) -> np.ndarray:
        """Wall milliseconds per frame: the stages' sum less what ran beside them (``serial``:
        the sum alone)."""
        n = self.frames
        parts = [self.ms[k][:n] for k in STAGES if len(self.ms[k]) >= n and n]
        if not parts:
            return np.zeros(0)
        total = np.sum(parts, axis=0)
        return total if serial or len(self.hidden) < n else total - np.asarray(self.hidden[:n])

    def first_suspicious(self) -> tuple[int, str] | None:
        """Index and reason of the first frame flagged by the divergence detector."""
        for i, h in enumerate(self.odometry.health):
            if h.suspicious:
                return i, h.why
        return None


@dataclass
class FrameRecord:
    """What the caller (progress bar, viewer) sees after every frame."""

    frame: ClassifiedFrame
    index: int
    kept: dict[str, np.ndarray]  # variant -> mask of the points given to ICP
    poses: dict[str, np.ndarray]  # variant -> pose of this frame (first frame = identity)
    runs: dict[str, VariantRun]  # the runs so far (stage times, counts, odometry state)

    def ms(self, variant: str) -> dict[str, float]:
        """This frame's milliseconds per stage of ``variant``."""
        return {k: v[-1] for k, v in self.runs[variant].ms.items() if v}

    def health(self, variant: str) -> dict[str, Any]:
        """This frame's registration health of ``variant`` (``FrameHealth.as_dict``: inliers,
        inlier_fraction, mean_residual_m, threshold_m, iterations, suspicious, why)."""
        return self.runs[variant].odometry.health[-1].as_dict()


@dataclass
class CompareResult:
    runs: dict[str, VariantRun]
    gt_poses: np.ndarray | None
    times: np.ndarray
    names: list[str]
    skipped: dict[str, str] = field(default_factory=dict)
    disagreements: dict[str, dict] = field(default_factory=dict)
    guard: GuardConfig = field(default_factory=GuardConfig)

    def health(self) -> dict[str, VariantHealth]:
        """Each variant's health over the run (:func:`~prc_slam.odometry.guard.judge_variant`):
        ok, untrustworthy (mostly suspicious frames, or disagreeing with every other variant for
        most of the run) or failed."""
        frames = {name: run.frames for name, run in self.runs.items()}
        return {
            name: judge_variant(
                name,
                [h.suspicious for h in run.odometry.health[: run.frames]],
                frames,
                self.disagreements,
                self.guard,
                run.failed,
            )
            for name, run in self.runs.items()
        }

    def estimate_in_world(self, name: str) -> np.ndarray:
        """A variant's poses in the ground truth's world frame (started at its first pose); a
        failed variant's cover the frames before its failure."""
        poses = self.runs[name].poses
        return poses if self.gt_poses is None or not len(poses) else self.gt_poses[0] @ poses

    def metrics(self) -> dict[str, Any]:
        """The ``compare`` metrics JSON of DESIGN.md (plus per-stage times, class counts, the
        per-frame health of every variant and, for a failed variant, where and why; ``health``
        ``"ok"``, ``"untrustworthy"`` or ``"failed"`` per variant with ``health_reason``,
        ``trusted_variants`` and, when there is none, ``no_variant_trusted``: the line that leads
        the report)."""
        out: dict[str, Any] = {}
        verdict = self.health()
        for name, run in self.runs.items():
            n = run.frames
            ms = run.ms_per_frame()
            m: dict[str, Any] = {
                "frames": n,
                "failed": run.failed is not None,
                "ms_per_frame": float(np.mean(ms)) if n else None,
                "ms_per_frame_median": float(np.median(ms)) if n else None,
                "points_in": float(np.mean(run.points_in)) if n else None,
                "points_to_icp": float(np.mean(run.points_to_icp)) if n else None,
                "ms_per_stage": {k: float(np.mean(v)) for k, v in run.ms.items() if v},
                "ms_per_frame_serial": float(np.mean(run.ms_per_frame(serial=True))) if n else None,
                "ms_overlapped": float(np.mean(run.hidden[:n])) if n and len(run.hidden) >= n else None,
                "ms_health": float(np.mean(run.odometry.health_ms)) if run.odometry.health_ms else None,
                # frames given the predicted pose, too few points to register (kiss.MIN_SOURCE_POINTS)
                "coasted_frames": [i for i in run.odometry.coasted if i < n],
                # directions the matched surfaces did not constrain (odometry.degeneracy), per frame
                "degenerate_frames": [d for d in run.odometry.degenerate_frames if d["frame"] < n],
            }
            if run.failed is not None:
                m["failed_at_frame"] = run.failed["frame"]
                m["failure_reason"] = run.failed["reason"]
            health = run.odometry.health[:n]
            flagged = [i for i, h in enumerate(health) if h.suspicious]
            first = run.first_suspicious()
            m["suspicious_frames"] = flagged
            m["health"] = verdict[name].status
            m["health_reason"] = verdict[name].reason or None
            m["first_suspicious_frame"] = None if first is None else first[0]
            m["first_suspicious_reason"] = None if first is None else first[1]
            m["per_frame"] = {
                "ms_wall": ms.tolist(),
                "inliers": [h.inliers for h in health],
                "source_points": [h.source_points for h in health],
                "inlier_fraction": [h.inlier_fraction for h in health],
                "mean_residual_m": [h.mean_residual_m for h in health],
                "threshold_m": [h.threshold_m for h in health],
                "iterations": [h.iterations for h in health],
                "suspicious": [h.suspicious for h in health],
                "degeneracy_ratio": [None if c is None else c.ratio for c in run.odometry.conditioning[:n]],
            }
            if getattr(run.odometry, "ground", None) is not None and run.counts_in:
                # frames whose height, roll and pitch the ground refinement moved (odometry.ground)
                m["ground_refined_frames"] = sorted(i for i in run.odometry.ground_refined if i < n)
            if run.counts_in:  # frames deskewed again with their registered motion (odometry.redeskew)
                m["redeskewed_frames"] = sorted(i for i in run.odometry.redeskewed if i < n)
            if run.counts_in:
                m["points_in_per_class"] = run.counts_in
                m["points_kept_per_class"] = run.counts_kept
            if isinstance(run.odometry, ClassAwareOdometry) and n:
                per_frame = np.array(run.odometry.correspondences[:n]).reshape(-1, len(GROUP_NAMES))
                m["correspondences_per_group"] = {g: per_frame[:, i].tolist() for i, g in enumerate(GROUP_NAMES)}
                m["correspondences_per_group_mean"] = {
                    g: float(per_frame[:, i].mean()) for i, g in enumerate(GROUP_NAMES)
                }
                # sweeps matched class-aware; the others fell back to the prc registration (too few anchors)
                m["classaware_frames"] = [i for i in run.odometry.classaware_frames if i < n]
                # of those anchored, the sweeps whose class-aware ICP ended at its iteration limit
                m["unconverged_frames"] = [i for i in run.odometry.unconverged_frames if i < n]
                # of the class-aware sweeps, those whose velocity registered with the pose broke the guard's bounds
                m["sweep_rejected_frames"] = [i for i in run.odometry.sweep_rejected if i < n]
            if self.gt_poses is not None and n:
                est = self.estimate_in_world(name)
                gt = self.gt_poses[:n]
                # one pose has no error to measure (it is placed at the ground truth): null, not 0
                m["ate_rmse_m"] = E.ate_rmse(est, gt) if n > 1 else None
                m["rpe_trans_m"] = float(np.mean(E.rpe(est, gt))) if n > 1 else None
                m["kitti_trans_pct"], m["kitti_rot_deg_per_m"] = E.kitti_errors(est, gt)
                dist = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum()
                m["path_length_m"] = float(dist)
            out[name] = _json_safe(m)
        result: dict[str, Any] = {"variants": out, "trusted_variants": [n for n, h in verdict.items() if h.ok]}
        lead = no_trust_line(verdict)
        if lead is not None:
            result["no_variant_trusted"] = lead
        if self.skipped:
            result["skipped_variants"] = dict(self.skipped)
        if self.disagreements:
            result["disagreements"] = _json_safe(self.disagreements)
        return result


def _json_safe(v: Any) -> Any:
    """NaN/inf -> None (strict JSON), recursively."""
    if isinstance(v, float):
        return v if np.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_json_safe(x) for x in v]
    return v


def _peers():
    """The peer filters (``prc_slam.evaluation.peers``), or a clear error naming what is missing."""
    try:
        from prc_slam.evaluation import peers
    except ImportError as exc:  # the module or its package
        raise PeerMissing(f"peer variants need prc_slam.evaluation.peers ({exc})") from exc
    return peers


class PeerMissing(RuntimeError):
    """A peer variant cannot run here (module or package missing)."""


def _check_peers(names: list[str]) -> dict[str, str]:
    """Peer variants that cannot run here, with the reason (module or package missing)."""
    if not names:
        return {}
    try:
        peers = _peers()
    except PeerMissing as exc:
        return dict.fromkeys(names, str(exc))
    probe = np.random.default_rng(0).uniform(-10, 10, (64, 3))
    probe[:, 2] = np.abs(probe[:, 2]) * 0.1 - 1.7
    skipped = {}
    for name in names:
        fn = {"sor": "statistical_outlier_keep", "ror": "radius_outlier_keep", "patchwork": "patchwork_ground"}[name]
        try:
            getattr(peers, fn)(probe)
        except peers.PeerUnavailable as exc:
            skipped[name] = str(exc)
    return skipped


def _select(name: str, pts: np.ndarray, labels: np.ndarray | None, frame: ClassifiedFrame, config: Config):
    """The points ``name`` gives to registration: ``(keep, labels for the odometry, filter result
    or None)``. Timed by the caller as the ``filter`` stage."""
    if name == "raw":
        return np.ones(len(pts), dtype=bool), None, None
    if name in ("prc", "prc+classaware"):
        res = filter_points(pts, labels, config.filter, frame.point_one_sided())
        return res.keep, labels, res
    peers = _peers()
    if name == "sor":
        return np.asarray(peers.statistical_outlier_keep(pts), dtype=bool), None, None
    if name == "ror":
        return np.asarray(peers.radius_outlier_keep(pts), dtype=bool), None, None
    if name == "patchwork":
        # Patchwork++'s ground treated as the prc variant treats PRC ground (thinned the same way)
        ground = np.asarray(peers.patchwork_ground(pts), dtype=bool)
        codes = np.where(ground, L.GROUND, L.UNCLASSIFIED).astype(np.uint8)
        res = filter_points(pts, codes, config.filter)
        return res.keep, codes, res
    raise ValueError(f"unknown variant {name!r}")


def _without(interval: tuple[float, float], holes: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """``interval`` less the (disjoint) ``holes``, as a list of intervals."""
    out, start = [], interval[0]
    for h0, h1 in sorted(holes):
        if h0 > start:
            out.append((start, min(h0, interval[1])))
        start = max(start, h1)
    if start < interval[1]:
        out.append((start, interval[1]))
    return [(a, b) for a, b in out if b > a]


def warm_up_kernels(config: Config) -> None:
    """Compile (or load) the numba kernels of the filter, the deskewing and the guard before
    anything is timed."""
    from prc_slam.odometry.ground import GroundModel
    from prc_slam.odometry.group_map import GroupVoxelMap
    from prc_slam.odometry.guard import residuals
    from prc_slam.odometry.kiss import deskew_points

    pts = np.random.default_rng(0).uniform(-5, 5, (64, 3))
    codes = np.full(64, L.GROUND, np.uint8)
    for dtype in (np.float64, np.float32):  # simulated sweeps give float64 points, most readers float32
        filter_points(pts.astype(dtype), codes, config.filter, np.zeros(64, bool))
    deskew_points(pts, np.linspace(0, 0.1, 64), 0.05, 0.1, np.eye(4))
    gmap = GroupVoxelMap(1.0, 100.0, 20)
    gmap.update(pts, np.zeros(64, np.int64), np.eye(4))
    residuals(pts, np.zeros(64, np.int64), *gmap.index(), 1.0, 1.0, np.eye(4))
    if config.odometry.ground.enabled:
        ground = GroundModel(config.odometry.ground, 100.0)
        ground.update(pts, np.eye(4))
        ground.refine(pts, np.eye(4), 1.0)


def _frame_time(scan: Scan, times: np.ndarray | None = None) -> float | None:
    """The instant every variant's pose of ``scan`` refers to: the frame's own time
    (``scan.meta["frame_time"]``), else the middle of the time span of all its points
    (``times``), else None (each odometry's clock then goes on from its previous frames).

    The odometries' clocks (:class:`~prc_slam.odometry.kiss.FrameClock`) take the same middle of
    the points they are given; taken here over every point, all variants' poses refer to one
    instant, the instant written to ``frames.txt`` and the TUM trajectories (Ouster sweeps carry
    no frame time: those files said 0, 1, 2 s, the frame index, for sweeps 0.1 s apart)."""
    t = scan.meta.get("frame_time")
    if t is not None and np.isfinite(t):
        return float(t)
    if times is None:
        return None
    finite = np.asarray(times, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return 0.5 * (float(finite.min()) + float(finite.max())) if len(finite) else None


class OdometryVariants:
    """The odometry variants as one pipeline stage (:class:`prc_slam.pipeline.Pipeline`): every
    frame is filtered and registered by each variant in turn, so machine noise hits all alike.

    A variant whose odometry fails (non-finite pose, pose jump beyond the guard's bounds, ICP not
    converged, or any error inside it) stops at that frame with the reason in ``failed``; the
    other variants go on, unaffected. A peer variant whose package is missing is left out with a
    warning (``CompareResult.skipped``).
    """

    def __init__(self, config: Config, variants: Iterable[str] = DEFAULT_VARIANTS) -> None:
        variants = list(variants)
        if not variants:
            raise ValueError("--variants: give at least one variant (e.g. raw,prc)")
        unknown = [v for v in variants if v not in VARIANTS]
        if unknown:
            raise ValueError(f"--variants: unknown variants {unknown}; choose from {list(VARIANTS)}")
        self.skipped = _check_peers([v for v in variants if v in PEER_VARIANTS])
        if self.skipped:
            warnings.warn("; ".join(f"skipping {v}: {why}" for v, why in self.skipped.items()), stacklevel=2)
        variants = [v for v in variants if v not in self.skipped]
        if not variants:
            raise ValueError("--variants: none of the variants can run here: " + "; ".join(self.skipped.values()))
        self.config = config
        self.runs = {
            v: VariantRun(
                v,
                ClassAwareOdometry(config.odometry, config.classaware)
                if v == "prc+classaware"
                else KissOdometry(config.odometry),
            )
            for v in variants
        }
        warm_up()
        warm_up_kernels(config)
        if "prc+classaware" in variants:
            try:
                classaware.warm_up()
            except Exception:  # compilation only; a broken odometry fails its variant on the first frame
                pass
        self.needs_prc = any(v in ("prc", "prc+classaware") for v in variants)
        first = next(iter(self.runs.values())).odometry
        self.agreement = AgreementMonitor(config.odometry.guard, first.voxel)
        self.gt: list[np.ndarray | None] = []
        self.times: list[float] = []
        self.names: list[str] = []

    def prepare(self, frame: ClassifiedFrame) -> ClassifiedFrame:
        """``frame`` with the PRC variants' filter applied (``filtered``, ``filter_seconds``, its
        span among ``spans``): it needs the frame and its labels only, so it is done as the frame
        is made, beside the registration of the frame before when that is made beside it
        (``odometry.overlap``), like organising and PRC. Frames without labels are left as they
        are."""
        if not self.needs_prc or frame.labels is None:
            return frame
        pts, labels, one_sided = frame.scan.points(), frame.point_labels(), frame.point_one_sided()
        t0 = time.perf_counter()  # the points and labels are every variant's input, charged to none (step)
        res = filter_points(pts, labels, self.config.filter, one_sided)
        t1 = time.perf_counter()
        return replace(frame, filtered=res, filter_seconds=t1 - t0, spans=(*frame.spans, (t0, t1)))

    @property
    def all_failed(self) -> bool:
        return all(r.failed is not None for r in self.runs.values())

    def step(self, index: int, frame: ClassifiedFrame, ahead: NextFrame | None = None) -> FrameRecord:
        """Filter and register one frame with every variant still running (once every variant
        has failed, frames are no longer recorded).

        The variants without PRC register first, alone. With ``ahead`` (and ``odometry.overlap``),
        the next frame is then read, organised and classified on a second thread while the PRC
        variants filter and register this one, taking turns at going first from frame to frame;
        the next frame's organising, PRC and filter time that ran beside them is credited to each
        (``VariantRun.hidden``, :meth:`_credit`).
        """
        config = self.config
        scan = frame.scan
        if self.all_failed:
            return FrameRecord(frame, index, {}, {}, self.runs)
        pts = scan.points()
        t = scan.point_times()
        frame_time = _frame_time(scan, t)
        kept: dict[str, np.ndarray] = {}
        poses: dict[str, np.ndarray] = {}
        labels = frame.point_labels() if self.needs_prc else None
        with_prc = [n for n in self.runs if n in PRC_VARIANTS]
        turn = index % len(with_prc) if with_prc else 0  # the PRC variants take turns at going first
        order = [n for n in self.runs if n not in PRC_VARIANTS] + with_prc[turn:] + with_prc[:turn]
        window = False  # the next frame is being made beside the PRC variants
        busy: dict[str, list[tuple[float, float]]] = {}  # PRC variant -> its filter and registration
        for name in order:
            run = self.runs[name]
            if run.failed is not None:
                continue
            if not window and name in PRC_VARIANTS and ahead is not None and config.odometry.overlap:
                ahead.start()
                window = True
            try:
                made = name in PRC_VARIANTS and frame.filtered is not None
                if name in PRC_VARIANTS:
                    run.ms["prc"].append(frame.seconds * 1e3)
                t0 = time.perf_counter()
                if made:  # filtered as the frame was made (prepare): charged as measured there
                    keep, codes, res = frame.filtered.keep, labels, frame.filtered
                else:
                    keep, codes, res = _select(name, pts, labels, frame, config)
                t1 = time.perf_counter()
                if name != "raw":
                    run.ms["filter"].append(frame.filter_seconds * 1e3 if made else (t1 - t0) * 1e3)
                sel = keep if res is None else res.kept_in_order  # PRC chooses what is registered, and in which order
                extra = {}
                if res is not None and res.source is not None:
                    # prc+classaware registers the same points as prc (only the matching differs): with
                    # all the kept ground (1 m grid) it lost a 16-beam walk at one sweep in 20
                    extra["source"] = res.source[sel]
                pose = run.odometry.register(
                    pts[sel], None if t is None else t[sel], None if codes is None else codes[sel], frame_time, **extra
                )  # fmt: skip
                t2 = time.perf_counter()
                # the guard's health (residuals on its shadow map) is monitoring, not registration
                run.ms["icp"].append((t2 - t1) * 1e3 - run.odometry.health_ms[-1])
            except Exception as exc:  # one variant's failure must not end the others
                reason = getattr(exc, "reason", None) or f"{type(exc).__name__}: {exc}"
                run.failed = {"frame": index, "reason": reason}
                for k in run.ms:  # stage times of the frames with a pose only
                    del run.ms[k][run.frames :]
                del run.hidden[run.frames :]
                if run.hidden:  # the credit for this frame's PRC, no longer charged
                    run.hidden[-1] = 0.0
                continue
            if window:  # the health residuals are monitoring, charged to no variant: nothing hides behind them
                busy[name] = [(t0, t1), *_without((t1, t2), run.odometry.health_spans)]
            run.hidden.append(0.0)
            poses[name] = pose
            if res is not None:
                for k, n in res.counts_in.items():
                    run.counts_in[k] = run.counts_in.get(k, 0) + n
                for k, n in res.counts_kept.items():
                    run.counts_kept[k] = run.counts_kept.get(k, 0) + n
            run.points_in.append(len(pts))
            run.points_to_icp.append(int(keep.sum()))
            kept[name] = keep
        if window:
            ahead.wait()
            self._credit(self.runs, busy, ahead)
        self._cross_check(index, pts, poses)
        self.gt.append(scan.gt_pose)
        self.times.append(self._time_of(frame_time, poses))
        self.names.append(scan.name)
        return FrameRecord(frame, index, kept, poses, self.runs)

    def _time_of(self, frame_time: float | None, poses: dict[str, np.ndarray]) -> float:
        """The time of this frame in the outputs: ``frame_time``, else the time a variant that
        registered the frame gave it (its clock goes on at the last interval), else the previous
        frame's plus 0.1 s."""
        if frame_time is not None:
            return frame_time
        for name in poses:
            return self.runs[name].odometry.clock.times[-1]
        return self.times[-1] + 0.1 if self.times else 0.0

    @staticmethod
    def _credit(runs: dict[str, VariantRun], busy: dict[str, list[tuple[float, float]]], ahead: NextFrame) -> None:
        """Credit the PRC variants the charged work of the second thread that ran beside theirs.

        ``busy``: each PRC variant's filter and registration in the window (not its health
        residuals, which are charged to no variant), as ``time.perf_counter()`` intervals (one
        variant after the other on this thread). Of the second thread's work only organising, PRC
        and the filter are charged (``NextFrame.charged``: the next frame's PRC and filter
        (:meth:`prepare`) and, with a read-ahead, the organising of the frame after; reading is no
        variant's cost). The part of those intervals
        beside any PRC variant's work is credited to each (at most its own filter and registration
        time): each PRC variant is charged every frame's organising and PRC in full when it is
        consumed, including the time it spent waiting beside another variant's registration
        (KISS-ICP holds the GIL).
        """
        spans = [s for intervals in busy.values() for s in intervals]
        beside = 1e3 * sum(max(0.0, min(t1, s1) - max(t0, s0)) for t0, t1 in spans for s0, s1 in ahead.charged)
        for name, intervals in busy.items():
            runs[name].hidden[-1] = min(beside, 1e3 * sum(t1 - t0 for t0, t1 in intervals))

    def _cross_check(self, index: int, pts: np.ndarray, poses: dict[str, np.ndarray]) -> None:
        """Hold the variants that registered this frame against each other
        (:class:`~prc_slam.odometry.agreement.AgreementMonitor`); a suspect's frame is flagged in
        its health. Monitoring, timed with the health, not in any variant's stage times."""
        t0 = time.perf_counter()
        registered = {name: self.runs[name].odometry for name in poses}
        flags = self.agreement.update(index, pts, {name: odo.poses for name, odo in registered.items()})
        for name, why in flags.items():
            health = registered[name].health[-1]
            health.suspicious = True
            health.why = "; ".join(filter(None, [health.why, why]))
        ms = (time.perf_counter() - t0) * 1e3 / max(len(registered), 1)
        for odo in registered.values():
            odo.health_ms[-1] += ms

    def result(self) -> CompareResult:
        gt = self.gt
        gt_poses = np.array(gt) if gt and all(g is not None for g in gt) else None
        return CompareResult(
            self.runs, gt_poses, np.asarray(self.times, dtype=float), self.names, self.skipped,
            self.agreement.as_dict(), self.config.odometry.guard,
        )  # fmt: skip


def run_compare(
    scans: Iterable[Scan],
    config: Config,
    variants: Iterable[str] = DEFAULT_VARIANTS,
    on_frame: Callable[[FrameRecord], None] | None = None,
) -> CompareResult:
    """Run every variant over ``scans`` in one pass (see :class:`OdometryVariants`); stops when
    every variant has failed."""
    stage = OdometryVariants(config, variants)
    read = ReadAhead(scans)
    frames = classify_frames(read, config.prc) if stage.needs_prc else unclassified(read)
    ahead = NextFrame(map(stage.prepare, frames), read)
    i = 0
    try:
        while (frame := ahead.take()) is not None:
            record = stage.step(i, frame, ahead)
            if on_frame is not None and record.poses:
                on_frame(record)
            if stage.all_failed:
                break
            i += 1
    finally:
        ahead.wait()
    return stage.result()
