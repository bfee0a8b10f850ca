"""Run odometry variants side by side in one process over the same frames.

Variants: ``raw`` (every point to KISS-ICP), ``prc`` (PRC labels, then the filter policy of
:mod:`prc_slam.filtering`, then KISS-ICP with the same settings) and ``prc+classaware`` (the
same filtered points with their labels to :class:`~prc_slam.odometry.classaware.ClassAwareOdometry`).
Each frame is read once and given to every variant in turn, so machine noise hits all variants
alike.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from prc_slam import evaluation as E
from prc_slam.config import Config
from prc_slam.filtering import filter_points
from prc_slam.odometry import classaware
from prc_slam.odometry.classaware import GROUP_NAMES, ClassAwareOdometry
from prc_slam.odometry.kiss import KissOdometry
from prc_slam.pipeline import ClassifiedFrame, classify_frames
from prc_slam.prc.algorithm import warm_up
from prc_slam.scan import Scan

VARIANTS = ("raw", "prc", "prc+classaware")
DEFAULT_VARIANTS = ("raw", "prc")


@dataclass
class VariantRun:
    """Per-frame record of one variant."""

    name: str
    odometry: KissOdometry | ClassAwareOdometry
    ms: dict[str, list[float]] = field(default_factory=lambda: {"prc": [], "filter": [], "icp": []})
    points_in: list[int] = field(default_factory=list)
    points_to_icp: list[int] = field(default_factory=list)
    counts_in: dict[str, int] = field(default_factory=dict)
    counts_kept: dict[str, int] = field(default_factory=dict)

    @property
    def poses(self) -> np.ndarray:
        return np.array(self.odometry.poses)

    def ms_per_frame(self) -> np.ndarray:
        return np.sum([self.ms[k] for k in self.ms if self.ms[k]], axis=0)


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


@dataclass
class CompareResult:
    runs: dict[str, VariantRun]
    gt_poses: np.ndarray | None
    times: np.ndarray
    names: list[str]

    def estimate_in_world(self, name: str) -> np.ndarray:
        """A variant's poses in the ground truth's world frame (started at its first pose)."""
        poses = self.runs[name].poses
        return poses if self.gt_poses is None else self.gt_poses[0] @ poses

    def metrics(self) -> dict[str, Any]:
        """The ``compare`` metrics JSON of DESIGN.md (plus per-stage times and class counts)."""
        out: dict[str, Any] = {}
        for name, run in self.runs.items():
            m: dict[str, Any] = {
                "frames": len(run.points_in),
                "ms_per_frame": float(np.mean(run.ms_per_frame())),
                "ms_per_frame_median": float(np.median(run.ms_per_frame())),
                "points_in": float(np.mean(run.points_in)),
                "points_to_icp": float(np.mean(run.points_to_icp)),
                "ms_per_stage": {k: float(np.mean(v)) for k, v in run.ms.items() if v},
            }
            if run.counts_in:
                m["points_in_per_class"] = run.counts_in
                m["points_kept_per_class"] = run.counts_kept
            if isinstance(run.odometry, ClassAwareOdometry):
                per_frame = np.array(run.odometry.correspondences).reshape(-1, len(GROUP_NAMES))
                m["correspondences_per_group"] = {g: per_frame[:, i].tolist() for i, g in enumerate(GROUP_NAMES)}
                m["correspondences_per_group_mean"] = {
                    g: float(per_frame[:, i].mean()) for i, g in enumerate(GROUP_NAMES)
                }
            if self.gt_poses is not None:
                est = self.estimate_in_world(name)
                m["ate_rmse_m"] = E.ate_rmse(est, self.gt_poses)
                m["rpe_trans_m"] = float(np.mean(E.rpe(est, self.gt_poses))) if len(est) > 1 else 0.0
                m["kitti_trans_pct"], m["kitti_rot_deg_per_m"] = E.kitti_errors(est, self.gt_poses)
                dist = np.linalg.norm(np.diff(self.gt_poses[:, :3, 3], axis=0), axis=1).sum()
                m["path_length_m"] = float(dist)
            out[name] = m
        return {"variants": out}


class OdometryVariants:
    """The odometry variants as one pipeline stage: every frame is filtered and registered by each
    variant in turn (so machine noise hits all variants alike).

    ``step(index, frame)`` takes a :class:`~prc_slam.pipeline.ClassifiedFrame` (PRC labels needed
    by every variant but ``raw``) and returns the frame's :class:`FrameRecord`; ``result()`` the
    :class:`CompareResult` so far.
    """

    def __init__(self, config: Config, variants: Iterable[str] = DEFAULT_VARIANTS) -> None:
        variants = list(variants)
        if not variants:
            raise ValueError("--variants: give at least one variant")
        unknown = [v for v in variants if v not in VARIANTS]
        if unknown:
            raise ValueError(f"--variants: unknown variants {unknown}; choose from {list(VARIANTS)}")
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
        self.needs_prc = any(v != "raw" for v in variants)
        warm_up()
        if "prc+classaware" in variants:
            classaware.warm_up()
        self.gt: list[np.ndarray | None] = []
        self.times: list[float] = []
        self.names: list[str] = []

    def step(self, index: int, frame: ClassifiedFrame) -> FrameRecord:
        """Filter and register one frame with every variant."""
        config = self.config
        scan = frame.scan
        pts = scan.points()
        t = scan.point_times()
        kept: dict[str, np.ndarray] = {}
        poses: dict[str, np.ndarray] = {}
        labels = frame.point_labels() if self.needs_prc else None
        for name, run in self.runs.items():
            if name == "raw":
                keep = np.ones(len(pts), dtype=bool)
            else:
                run.ms["prc"].append(frame.seconds * 1e3)
                t0 = time.perf_counter()
                res = filter_points(pts, labels, config.filter, frame.point_one_sided())
                keep = res.keep
                run.ms["filter"].append((time.perf_counter() - t0) * 1e3)
                for k, n in res.counts_in.items():
                    run.counts_in[k] = run.counts_in.get(k, 0) + n
                for k, n in res.counts_kept.items():
                    run.counts_kept[k] = run.counts_kept.get(k, 0) + n
            t0 = time.perf_counter()
            poses[name] = run.odometry.register(
                pts[keep], None if t is None else t[keep], None if labels is None else labels[keep]
            )
            run.ms["icp"].append((time.perf_counter() - t0) * 1e3)
            run.points_in.append(len(pts))
            run.points_to_icp.append(int(keep.sum()))
            kept[name] = keep
        self.gt.append(scan.gt_pose)
        self.times.append(scan.meta.get("frame_time", float(index)))
        self.names.append(scan.name)
        return FrameRecord(frame, index, kept, poses, self.runs)

    def result(self) -> CompareResult:
        gt = self.gt
        gt_poses = np.array(gt) if gt and all(g is not None for g in gt) else None
        return CompareResult(self.runs, gt_poses, np.asarray(self.times, dtype=float), self.names)


def run_compare(
    scans: Iterable[Scan],
    config: Config,
    variants: Iterable[str] = DEFAULT_VARIANTS,
    on_frame: Callable[[FrameRecord], None] | None = None,
) -> CompareResult:
    """Run every variant over ``scans`` in one pass (PRC first when a variant needs it)."""
    stage = OdometryVariants(config, variants)
    frames = classify_frames(scans, config.prc) if stage.needs_prc else (ClassifiedFrame(s, None, 0.0) for s in scans)
    for i, frame in enumerate(frames):
        record = stage.step(i, frame)
        if on_frame is not None:
            on_frame(record)
    return stage.result()
