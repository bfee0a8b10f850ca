"""Pipeline sinks that write files or log to Rerun (application layer: they use ``data_tools``
writers and ``prc_slam.viz``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from prc_slam.pipeline import PipelineFrame, PipelineResult


def _codes(step: PipelineFrame, source: str) -> np.ndarray:
    """Per-point codes of a frame from ``source``: ``prc`` labels or ``online`` detector labels."""
    if source == "online":
        return step.scan.per_point(step.online.labels)
    return step.frame.point_labels()


class LabelFiles:
    """One ``NNNNNN.label`` per frame (uint32, our code in the lower 16 bits, input order)."""

    def __init__(self, out: Path, source: str = "prc") -> None:
        self.out, self.source = Path(out), source
        self.written = 0

    def frame(self, step: PipelineFrame) -> None:
        from data_tools.formats.writers import write_label_file

        write_label_file(self.out / f"{step.scan.name}.label", _codes(step, self.source))
        self.written += 1

    def close(self, result: PipelineResult) -> None:
        pass


class LasFile:
    """The labelled points of every frame (world frame when the frame has a ground-truth pose) as
    one LAS 1.4 file (LAZ when the name ends in ``.laz``), frame index in ``point_source_id``."""

    def __init__(self, path: Path, source: str = "prc") -> None:
        self.path, self.source = Path(path), source
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.written: Path | None = None

    def frame(self, step: PipelineFrame) -> None:
        scan = step.scan
        xyz = scan.points()
        if scan.gt_pose is not None:
            xyz = xyz @ scan.gt_pose[:3, :3].T + scan.gt_pose[:3, 3]
        self.parts.append((xyz, _codes(step, self.source)))

    def close(self, result: PipelineResult) -> None:
        if not self.parts or result.interrupted:
            return
        from data_tools.formats.writers import write_las

        write_las(
            self.path,
            np.concatenate([p[0] for p in self.parts]),
            np.concatenate([p[1] for p in self.parts]),
            point_source_id=np.concatenate([np.full(len(p[0]), i) for i, p in enumerate(self.parts)]),
        )
        self.written = self.path


class ViewerSink:
    """Logs every stage of a frame to Rerun: PRC labels and range images, the odometry variants
    (raw, filtered, map, trajectories, metrics) and the online detectors (labels, car boxes,
    curb strips) in the world frame of the ground truth or, without it, of the main estimate."""

    def __init__(self, viz) -> None:
        self.viz = viz

    def frame(self, step: PipelineFrame) -> None:
        scan = step.scan
        pose = scan.gt_pose
        if step.odometry is not None and step.odometry.poses:
            self.viz.log_record(step.odometry, gt_pose=scan.gt_pose)
            if pose is None:
                pose = self.viz.current_pose()
        elif step.frame.labels is not None:
            self.viz.log_classified(step.index, scan, step.frame.labels)
        elif step.online is not None:
            self.viz.log_classified(step.index, scan, step.online.labels)
        if step.online is not None:
            self.viz.log_online(step.index, scan, step.online, pose)

    def close(self, result: PipelineResult) -> None:
        for skip in result.skipped:
            self.viz.warn(f"skipped frame {skip.index}: {skip.reason}")
