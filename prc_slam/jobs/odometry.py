"""The ``compare``, ``odometry``, ``view`` and ``demo`` jobs: odometry variants side by side (with
PRC, the filter policy and, on request, the online detectors) over one input."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam.config import Config
from prc_slam.jobs.common import Viewer, frames_of, open_input, write_json
from prc_slam.jobs.progress import Reporter
from prc_slam.jobs.sinks import ViewerSink
from prc_slam.pipeline import Pipeline, PipelineFrame, PipelineResult

log = logging.getLogger("prc_slam")


@dataclass
class OdometryRun:
    """What an odometry job produced."""

    result: Any  # prc_slam.odometry.compare.CompareResult
    pipeline: PipelineResult
    metrics: dict[str, Any]
    online: dict[str, Any] | None = None
    prc: dict[str, Any] | None = None
    written: list[Path] = field(default_factory=list)


class _KeepPRCLabels:
    """Keeps the PRC labels of every ``every``-th frame (for ``--mapclass``)."""

    def __init__(self, every: int) -> None:
        self.every = every
        self.labels: dict[int, np.ndarray] = {}

    def frame(self, step: PipelineFrame) -> None:
        if step.index % self.every == 0 and step.frame.labels is not None:
            self.labels[step.index] = step.frame.point_labels()

    def close(self, result: PipelineResult) -> None:
        pass


def run_odometry(
    input: Path,
    config: Config,
    variants: Sequence[str],
    *,
    fmt: str | None = None,
    max_frames: int | None = None,
    stride: int = 1,
    online: bool = False,
    score_prc: bool = False,
    viewer: Viewer | None = None,
    reporter: Reporter | None = None,
    keep_labels_every: int | None = None,
    **open_options: Any,
) -> tuple[OdometryRun, dict[int, np.ndarray]]:
    """Run the odometry variants (and the online detectors with ``online``) over ``input``."""
    from prc_slam.odometry.compare import OdometryVariants
    from prc_slam.scoring import OnlineScorer, PRCScorer

    variants = list(variants)
    stage = OdometryVariants(config, variants)
    dataset, n = open_input(input, fmt, max_frames, stride, **open_options)
    viewer = viewer or Viewer()
    sinks: list = []
    online_scorer = prc_scorer = None
    detector = None
    if online:
        from prc_slam.online import OnlineDetector

        detector = OnlineDetector()
        online_scorer = OnlineScorer()
        sinks.append(online_scorer)
    if score_prc and stage.needs_prc:
        prc_scorer = PRCScorer()
        sinks.append(prc_scorer)
    keeper = None
    if keep_labels_every is not None:
        keeper = _KeepPRCLabels(keep_labels_every)
        sinks.append(keeper)
    if viewer.sink is not None:
        viewer.sink.config.variants = variants
        sinks.append(ViewerSink(viewer.sink))
    task = None if reporter is None else reporter.task("odometry " + " | ".join(variants), n)
    done = [0]

    def on_frame(step: PipelineFrame) -> None:
        done[0] = step.index + 1
        if task is not None:
            task.advance()

    pipe = Pipeline(
        prc=config.prc if stage.needs_prc else None, online=detector, odometry=stage, sinks=sinks, on_frame=on_frame
    )
    try:
        presult = pipe.run(frames_of(dataset, n))
    except KeyboardInterrupt:
        viewer.close(interrupted_at=done[0])
        raise
    result = presult.odometry
    metrics = result.metrics()
    metrics.update(presult.summary())
    note = unchecked_health_note(metrics.get("frames"), config.odometry.guard.warm_up)
    if note is not None:
        metrics["health_note"] = note
        log.warning(note)
    run = OdometryRun(result, presult, metrics)
    if online_scorer is not None:
        run.online = online_scorer.metrics(presult)
        metrics["online"] = run.online
    if prc_scorer is not None:
        run.prc = prc_scorer.metrics(presult)
        metrics["prc"] = run.prc
    written = viewer.close()
    if written is not None:
        run.written.append(written)
    return run, ({} if keeper is None else keeper.labels)


def unchecked_health_note(frames: int | None, warm_up: int) -> str | None:
    """A note for runs too short for the health checks: the divergence monitor starts at frame
    ``warm_up``, counting from 0 (:class:`~prc_slam.odometry.guard.GuardConfig`), and the variants'
    agreement holds them to bounds three times wider before it (:mod:`prc_slam.odometry.agreement`),
    so a run of that many frames or fewer is 'ok' without the full checks (KITTI 00 at
    ``--stride 5``, four keyframes: prc+classaware stopped 3.8 m short of the first 4.3 m step)."""
    if not frames or frames > warm_up:
        return None
    return (
        f"only {frames} frame{'s' if frames != 1 else ''}: the health checks start at frame {warm_up}, counting "
        "from 0 (before it only variants that part grossly are flagged), so 'ok' here means 'did not stop'"
    )


def write_outputs(run: OdometryRun, config: Config, out: Path, title: str) -> list[Path]:
    """report.md, metrics.json, trajectories (KITTI and TUM), config.yaml, trajectories.png and
    frames.txt (the time and input frame of each line of the KITTI-format trajectories)."""
    from data_tools.trajectory_io import write_kitti_poses, write_tum_poses
    from prc_slam.report import classification_section, write_compare_outputs

    metrics, written = write_compare_outputs(run.result, config, out, title, write_kitti_poses, write_tum_poses)
    extra = {k: v for k, v in run.metrics.items() if k != "variants"}
    if extra:
        metrics.update(extra)
        write_json(out / "metrics.json", metrics)
    with (out / "report.md").open("a") as f:
        f.write("\n![trajectories](trajectories.png)\n")
        skips = run.metrics.get("skips") or []
        if skips:
            f.write(
                f"\n## Skipped frames ({len(skips)})\n\nThe KITTI-format trajectories have one line per registered "
                "frame, so they are shorter than the input: `frames.txt` names the frame of each line (the TUM "
                "files carry the times).\n\n" + "".join(f"- input frame {s['index']}: {s['reason']}\n" for s in skips)
            )
        if run.metrics.get("ended_early"):
            f.write(f"\n**Ended early**: {run.metrics['ended_early']}; every output covers the frames before.\n")
        if "health_note" in run.metrics:
            f.write(f"\n**Health not checked**: {run.metrics['health_note']}.\n")
        if run.prc is not None:
            f.write(classification_section(run.prc, "PRC labels against the reference"))
        if run.online is not None:
            f.write(classification_section(run.online, "Online detectors against the reference"))
    run.metrics = metrics
    return written


def trajectory_file(run: OdometryRun, name: str, path: Path, pose_format: str = "kitti") -> Path:
    """Write one variant's trajectory (KITTI or TUM text, readable by evo)."""
    from data_tools.trajectory_io import write_kitti_poses, write_tum_poses

    poses = run.result.estimate_in_world(name)
    if pose_format == "kitti":
        write_kitti_poses(path, poses)
    else:
        write_tum_poses(path, run.result.times[: len(poses)], poses)  # a failed variant's poses stop early
    return path
