"""The ``filter`` job: every sweep through PRC and the filter policy, written back as a stream of
the input's kind (bag/MCAP with a ``label`` field, a PCD folder, KITTI bins) for any SLAM system."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from prc_slam.config import Config
from prc_slam.jobs.common import frames_of, open_input
from prc_slam.jobs.progress import Reporter
from prc_slam.pipeline import Pipeline
from prc_slam.scan import Scan


def run_filter(
    dataset: Iterable[Scan],
    out: str | Path,
    config: Config,
    *,
    keep_labels: Sequence[str | int] | None = None,
    progress: Callable[[int, int | None], None] | None = None,
    out_format: str | None = None,
    label_dtype: str = "uint8",
    overwrite: bool = False,
    writer_factory: Callable[..., Any] | None = None,
    frames: int | None = None,
) -> dict[str, Any]:
    """Classify every sweep of ``dataset`` with PRC, filter it and write the kept points to ``out``.

    Parameters
    ----------
    dataset : a Dataset (``data_tools.open_dataset``) or any iterable of Scans
    out : output path (a ``.mcap`` file, a ``.bag`` file, a rosbag2 folder, a PCD or KITTI folder)
    config : ``prc_slam.config.Config`` (its ``prc`` and ``filter`` parts are used)
    keep_labels : label names or codes; replaces the policy by "keep exactly these classes"
    progress : callable(frames_done, frames_total_or_None), called after every frame
    out_format : ``mcap``, ``ros2``, ``ros1``, ``pcd`` or ``kitti``; default from the suffix of
        ``out``, else the input's own kind (see ``data_tools.stream_out.open_stream_writer``)
    label_dtype : ``uint8`` or ``uint16`` (type of the ``label`` field in bag/MCAP output)
    overwrite : replace an existing ``out``
    writer_factory : callable(out, dataset, out_format, label_dtype=, overwrite=) returning a
        writer with ``write(scan, keep, labels)``, ``close()``, ``format``; default
        ``data_tools.stream_out.open_stream_writer``
    frames : only the first ``frames`` sweeps of an indexable dataset (unreadable ones are
        skipped and counted)

    Returns
    -------
    dict
        ``{"frames", "points_in", "points_kept", "kept_fraction", "per_class": {name: {"in",
        "kept"}}, "out", "out_format", "keep_labels", "policy", "seconds", "prc_seconds"}``, the
        pipeline's counts (``skipped_frames``, ``skipped_points``, ``empty_frames``) and, when the
        reader organised the sweeps, ``organize`` (warnings and the worst collision share).
    """
    from prc_slam.filter_run import FilterSink, parse_keep_labels
    from prc_slam.prc.algorithm import warm_up

    if writer_factory is None:
        from data_tools.stream_out import open_stream_writer as writer_factory
    codes = parse_keep_labels(keep_labels)
    try:
        total: int | None = len(dataset) if frames is None else frames  # type: ignore[arg-type]
    except TypeError:
        total = None
    # the writer first: a format the input cannot give (bag output of a KITTI folder) is refused
    # before the kernels compile
    writer = writer_factory(Path(out), dataset, out_format, label_dtype=label_dtype, overwrite=overwrite)
    warm_up()
    sink = FilterSink(writer, config.filter, codes)
    on_frame = None if progress is None else (lambda step: progress(step.index + 1, total))
    scans = frames_of(dataset, frames) if frames is not None else dataset
    result = Pipeline(prc=config.prc, sinks=[sink], on_frame=on_frame).run(scans)
    metrics = sink.metrics()
    organize = metrics.pop("organize", None)
    metrics.update(result.summary())
    if organize is not None:
        metrics["organize"] = {**result.organize, **organize}
    metrics["frames"] = sink.frames
    metrics["out"] = str(out)
    metrics["seconds"] = result.wall_seconds
    return metrics


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
    dataset, n = open_input(input, fmt, max_frames, **open_options)
    task = None if reporter is None else reporter.task("filter", n)
    metrics = run_filter(
        dataset, out, config, keep_labels=keep_labels, out_format=out_format, label_dtype=label_dtype,
        overwrite=overwrite, frames=n, progress=None if task is None else (lambda _i, _n: task.advance()),
    )  # fmt: skip
    metrics["input"] = str(input)
    return metrics
