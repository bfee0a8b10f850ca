"""The ``compare``, ``odometry``, ``view`` and ``demo`` jobs: odometry variants side by side (with
PRC, the filter policy and, on request, the online detectors) over one input."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam.config import Config
from prc_slam.jobs.common import Viewer, frames_of, open_input, write_json
from prc_slam.jobs.progress import Reporter
from prc_slam.jobs.sinks import ViewerSink
from prc_slam.pipeline import Pipeline, PipelineFrame, PipelineResult
from prc_slam.util.signals import frame_boundaries

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


class Interrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C (or SIGTERM) after ``done`` of ``total`` frames. ``run`` holds what
    those frames produced (metrics marked ``interrupted``), or None when the frame in progress
    could not be finished (a first interrupt waits for it up to a few seconds:
    :func:`prc_slam.util.signals.frame_boundaries`); ``recording`` is the partial ``.rrd`` written, if
    any."""

    def __init__(self, done: int, total: int, run: OdometryRun | None, recording: Path | None) -> None:
        super().__init__(f"interrupted at frame {done} of {total}")
        self.done, self.total, self.run, self.recording = done, total, run, recording


class _KeepResult:
    """Keeps the pipeline's result, handed to the sinks also when the run is interrupted."""

    def __init__(self) -> None:
        self.result: PipelineResult | None = None

    def frame(self, step: PipelineFrame) -> None:
        pass

    def close(self, result: PipelineResult) -> None:
        self.result = result


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
    from prc_slam.evaluation.scoring import OnlineScorer, PRCScorer
    from prc_slam.odometry.compare import OdometryVariants

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
    kept = _KeepResult()
    sinks.append(kept)
    boundary = [lambda: None]

    def on_frame(step: PipelineFrame) -> None:
        done[0] = step.index + 1
        if task is not None:
            task.advance()
        boundary[0]()  # a Ctrl-C held until this frame was done is raised here

    pipe = Pipeline(
        prc=config.prc if stage.needs_prc else None, online=detector, odometry=stage, sinks=sinks, on_frame=on_frame
    )
    try:
        with frame_boundaries() as check:
            boundary[0] = check
            presult = pipe.run(frames_of(dataset, n))
    except KeyboardInterrupt:
        recording = viewer.close(interrupted_at=done[0])
        partial = None if kept.result is None else _partial_run(kept.result, n, config, online_scorer, prc_scorer)
        at = done[0] if partial is None else partial.metrics["interrupted_at_frame"]
        raise Interrupted(at, n, partial, recording) from None
    run = _finished_run(presult, config, online_scorer, prc_scorer)
    written = viewer.close()
    if written is not None:
        run.written.append(written)
    return run, ({} if keeper is None else keeper.labels)


def _partial_run(presult: PipelineResult, total: int, config: Config, *scorers) -> OdometryRun | None:
    """What the frames done before an interrupt produced, marked interrupted (``interrupted``,
    ``interrupted_at_frame``: the frames done, ``frames_in_input``); None when the interrupt landed
    inside a frame's registration (a variant holds a pose the frame list does not)."""
    result = presult.odometry
    if result is None:
        return None
    done = len(result.times)
    if any(r.frames > done for r in result.runs.values()):
        return None
    run = _finished_run(presult, config, *scorers)
    run.metrics.update(interrupted=True, interrupted_at_frame=done, frames_in_input=total)
    return run


def interrupted_line(stop: Interrupted, write: Callable[[OdometryRun], list[str]]) -> str:
    """Write the results of an interrupted run with ``write`` (returns what it wrote, named for
    the user) and the one line that says where the run stopped and what it left. A second
    interrupt while writing stops the writing (said)."""
    parts = []
    if stop.run is None:
        parts.append("the frame in progress could not be finished, no results written")
    else:
        try:
            names = write(stop.run)
            if names:
                parts.append("wrote " + ", ".join(names))
        except KeyboardInterrupt:
            parts.append("interrupted again while writing the results: they may be incomplete")
    if stop.recording is not None:
        parts.append(f"partial recording {stop.recording}")
    return f"interrupted at frame {stop.done} of {stop.total}" + (": " + "; ".join(parts) if parts else "")


def _finished_run(presult: PipelineResult, config: Config, online_scorer, prc_scorer) -> OdometryRun:
    """The run's metrics (variants, pipeline counts, health note, scores) from its result."""
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
    return run


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
    from data_tools.formats.trajectory_io import write_kitti_poses, write_tum_poses
    from prc_slam.jobs.report import classification_section, write_compare_outputs

    if run.metrics.get("interrupted"):  # the report's first line says so
        k, n = run.metrics["interrupted_at_frame"], run.metrics["frames_in_input"]
        covers = f"frames 0 to {k - 1}" if k else "no frame"
        title = f"Interrupted at frame {k} of {n}: {title[:1].lower()}{title[1:]} (every output covers {covers})"
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
    from data_tools.formats.trajectory_io import write_kitti_poses, write_tum_poses

    poses = run.result.estimate_in_world(name)
    if pose_format == "kitti":
        write_kitti_poses(path, poses)
    else:
        write_tum_poses(path, run.result.times[: len(poses)], poses)  # a failed variant's poses stop early
    return path
