"""The ``classify`` and ``detect`` jobs: PRC or the online detectors over a whole input, scored
against its ground truth, with label files, LAS and a Rerun recording on request."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from prc_slam.evaluation.scoring import OnlineScorer, PRCScorer
from prc_slam.jobs.common import Viewer, frames_of, open_input
from prc_slam.jobs.progress import Reporter
from prc_slam.jobs.sinks import LabelFiles, LasFile, ViewerSink
from prc_slam.pipeline import Pipeline
from prc_slam.prc.config import AutoPreset, PRCConfig

log = logging.getLogger("prc_slam.jobs")


@dataclass
class Outputs:
    """Where a job writes per-frame outputs."""

    labels_out: Path | None = None
    las: Path | None = None
    written: list[Path] = field(default_factory=list)


def _file_sinks(outputs: Outputs, source: str) -> tuple[list, LasFile | None]:
    sinks: list = []
    if outputs.labels_out is not None:
        sinks.append(LabelFiles(outputs.labels_out, source))
    las = None if outputs.las is None else LasFile(outputs.las, source)
    if las is not None:
        sinks.append(las)
    return sinks, las


def _written(viewer: Viewer, las: LasFile | None, outputs: Outputs) -> list[Path]:
    """Close the recording; the files and folders the run wrote."""
    written = [p for p in (viewer.close(), None if las is None else las.written) if p is not None]
    if outputs.labels_out is not None:
        written.append(outputs.labels_out)
    return written


def _interrupted_note(done: int, n: int, outputs: Outputs | None) -> str:
    """What an interrupted run leaves behind, for the warning before ``error: interrupted``."""
    text = f"interrupted after {done} of {n} frames"
    if outputs is not None and outputs.labels_out is not None:
        text += f"; {outputs.labels_out} holds the label files of those {done} frames only"
    if outputs is not None and outputs.las is not None:
        text += f"; {outputs.las} is not written"
    return text + "; no metrics written"


def _run(
    pipe: Pipeline,
    dataset,
    n: int,
    viewer: Viewer,
    reporter: Reporter | None,
    title: str,
    outputs: Outputs | None = None,
):
    task = None if reporter is None else reporter.task(title, n)
    if task is not None:
        pipe.on_frame = lambda _s: task.advance()
    if viewer.sink is not None:
        pipe.sinks.append(ViewerSink(viewer.sink))
    done = [0]
    inner = pipe.on_frame

    def counted(step) -> None:
        done[0] = step.index + 1
        if inner is not None:
            inner(step)

    pipe.on_frame = counted
    try:
        result = pipe.run(frames_of(dataset, n))
    except KeyboardInterrupt:
        log.warning("%s", _interrupted_note(done[0], n, outputs))
        viewer.close(interrupted_at=done[0])
        raise
    return result


def classify_job(
    input: Path,
    config: PRCConfig | None,
    *,
    mode: str = "urban",
    adaptive: bool | None = None,
    fmt: str | None = None,
    max_frames: int | None = None,
    outputs: Outputs | None = None,
    viewer: Viewer | None = None,
    reporter: Reporter | None = None,
    **open_options: Any,
) -> tuple[dict[str, Any], list[Path]]:
    """PRC on every frame of ``input``; returns the ``classify`` metrics (``config``: the PRC
    config used) and the files written. ``config`` None (``--preset auto``): the preset the
    first sweep's sensor calls for (:class:`AutoPreset`, in ``mode``, ``adaptive`` when
    given), said on the log."""
    from prc_slam.prc.algorithm import warm_up

    outputs = outputs or Outputs()
    viewer = viewer or Viewer()
    dataset, n = open_input(input, fmt, max_frames, **open_options)
    prc = config if config is not None else AutoPreset(mode, adaptive)
    warm_up()
    scorer = PRCScorer()
    sinks, las = _file_sinks(outputs, "prc")
    result = _run(Pipeline(prc=prc, sinks=[scorer, *sinks]), dataset, n, viewer, reporter, "PRC", outputs)
    metrics = scorer.metrics(result)
    metrics["input"] = str(input)
    if isinstance(prc, AutoPreset):  # (no sweep read: the paper's, as the choice would have been)
        config = prc.config or PRCConfig.named("paper", mode, adaptive)
    metrics["config"] = config.model_dump(mode="json")
    return metrics, _written(viewer, las, outputs)


class OneClassWatch:
    """Pipeline sink warning (once per run) when the online detectors put nearly every return of
    a frame in one class (:func:`prc_slam.pipeline.one_class`), as PRC's own check does: a map
    tile or aerial cloud given to ``detect`` came out 100 % 'vertical' without a word. Counts the
    frames (``frames_one_class``)."""

    def __init__(self) -> None:
        self.frames = 0

    def frame(self, step) -> None:
        from prc_slam.pipeline import one_class

        res = step.online
        if res is None or res.labels is None:
            return
        one = one_class(res.labels, step.scan.ranges)
        if one is None:
            return
        self.frames += 1
        if self.frames == 1:
            log.warning(
                "%s: the online detectors put %.1f%% of the returns in one class (%s): is this a sweep of a "
                "spinning sensor (not a map or an aerial tile: use mapclass), in metres?",
                step.scan.source,
                one[1],
                one[0],
            )

    def close(self, result) -> None:
        pass


def detect_job(
    input: Path,
    *,
    paper: bool = False,
    fmt: str | None = None,
    max_frames: int | None = None,
    outputs: Outputs | None = None,
    viewer: Viewer | None = None,
    reporter: Reporter | None = None,
    **open_options: Any,
) -> tuple[dict[str, Any], list[Path]]:
    """The online detectors (paper 001) on every frame; returns the ``detect`` metrics and files."""
    from prc_slam.online import OnlineDetector

    outputs = outputs or Outputs()
    viewer = viewer or Viewer()
    dataset, n = open_input(input, fmt, max_frames, **open_options)
    scorer = OnlineScorer()
    sinks, las = _file_sinks(outputs, "online")
    detector = OnlineDetector.paper() if paper else OnlineDetector()
    watch = OneClassWatch()
    pipe = Pipeline(online=detector, sinks=[scorer, watch, *sinks])
    result = _run(pipe, dataset, n, viewer, reporter, "online detectors", outputs)
    metrics = scorer.metrics(result)
    metrics["frames_one_class"] = watch.frames
    metrics["input"] = str(input)
    return metrics, _written(viewer, las, outputs)
