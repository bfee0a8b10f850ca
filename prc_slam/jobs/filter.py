"""The ``filter`` job: every sweep through PRC and the filter policy, written back as a stream of
the input's kind (bag/MCAP with a ``label`` field, a PCD folder, KITTI bins) for any SLAM system."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from prc_slam.config import Config
from prc_slam.jobs.common import frames_of, open_input
from prc_slam.jobs.progress import Reporter
from prc_slam.pipeline import Pipeline


def filter_job(
    input: Path,
    config: Config,
    out: Path,
    *,
    fmt: str | None = None,
    max_frames: int | None = None,
    keep_labels: Sequence[str | int] | None = None,
    out_format: str | None = None,
    label_dtype: str = "uint8",
    overwrite: bool = False,
    reporter: Reporter | None = None,
    **open_options: Any,
) -> dict[str, Any]:
    """Filter ``input`` into ``out``; returns the ``filter`` metrics (counts per class in / kept)."""
    from data_tools.stream_out import open_stream_writer
    from prc_slam.filter_run import FilterSink, parse_keep_labels
    from prc_slam.prc.algorithm import warm_up

    codes = parse_keep_labels(keep_labels)
    dataset, n = open_input(input, fmt, max_frames, **open_options)
    warm_up()
    writer = open_stream_writer(Path(out), dataset, out_format, label_dtype=label_dtype, overwrite=overwrite)
    sink = FilterSink(writer, config.filter, codes)
    task = None if reporter is None else reporter.task("filter", n)
    pipe = Pipeline(prc=config.prc, sinks=[sink], on_frame=None if task is None else lambda _s: task.advance())
    result = pipe.run(frames_of(dataset, n))
    metrics = {**sink.metrics(), **result.summary(), "points_in": sink.metrics()["points_in"]}
    metrics["out"] = str(out)
    metrics["input"] = str(input)
    metrics["seconds"] = result.wall_seconds
    return metrics
