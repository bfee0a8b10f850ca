"""Classify a whole input with PRC and score it: the ``classify`` job as a library call."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from prc_slam.pipeline import Pipeline, PipelineFrame, PipelineResult
from prc_slam.prc.algorithm import warm_up
from prc_slam.prc.config import PRCConfig
from prc_slam.scan import Scan
from prc_slam.scoring import SOLID_CLASSES, PRCScorer

__all__ = ["SOLID_CLASSES", "run_classification"]


class _LabelFiles:
    """Writes one ``.label`` file per frame through an injected writer (the core does not
    import the writers)."""

    def __init__(self, out: Path, writer: Callable[[Path, Any], None]) -> None:
        self.out, self.writer = out, writer

    def frame(self, step: PipelineFrame) -> None:
        self.writer(self.out / f"{step.scan.name}.label", step.frame.point_labels())

    def close(self, result: PipelineResult) -> None:
        pass


def run_classification(
    scans: Iterable[Scan],
    config: PRCConfig,
    *,
    labels_out: Path | None = None,
    label_writer: Callable[[Path, Any], None] | None = None,
    on_frame: Callable[[Any], None] | None = None,
) -> dict[str, Any]:
    """Run PRC over ``scans``; write per-frame label files when asked; score against ground truth.

    Parameters
    ----------
    label_writer : callable(path, codes), optional
        Writes one ``.label`` file (injected so the core does not import the writers).
    on_frame : callable(ClassifiedFrame), optional
        Called for every classified frame.

    Returns
    -------
    metrics : dict
        The ``classify`` metrics JSON of DESIGN.md.
    """
    warm_up()
    scorer = PRCScorer()
    sinks: list = [scorer]
    if labels_out is not None and label_writer is not None:
        sinks.append(_LabelFiles(labels_out, label_writer))
    pipe = Pipeline(prc=config, sinks=sinks, on_frame=None if on_frame is None else lambda s: on_frame(s.frame))
    return scorer.metrics(pipe.run(scans))
