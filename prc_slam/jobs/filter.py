"""The ``filter`` job: every sweep through PRC and the filter policy, written back as a stream of
the input's kind (bag/MCAP with a ``label`` field, a PCD folder, KITTI bins) for any SLAM system."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam import labels as L
from prc_slam.config import Config
from prc_slam.filtering import FilterConfig, choose_points, parse_keep_labels
from prc_slam.jobs.common import frames_of, open_input
from prc_slam.jobs.progress import Reporter
from prc_slam.pipeline import ClassifiedFrame, Pipeline
from prc_slam.scan import Scan, ScanError


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
        ``out``, else the input's own kind (see ``data_tools.formats.stream_out.open_stream_writer``)
    label_dtype : ``uint8`` or ``uint16`` (type of the ``label`` field in bag/MCAP output)
    overwrite : replace an existing ``out``
    writer_factory : callable(out, dataset, out_format, label_dtype=, overwrite=) returning a
        writer with ``write(scan, keep, labels)``, ``close()``, ``format``; default
        ``data_tools.formats.stream_out.open_stream_writer``
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
    from prc_slam.prc.algorithm import warm_up

    if writer_factory is None:
        from data_tools.formats.stream_out import open_stream_writer as writer_factory
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


def _count(labels: np.ndarray) -> np.ndarray:
    return np.bincount(np.asarray(labels, dtype=np.uint8), minlength=256)


class FilterSink:
    """Filters every classified frame and hands the kept points to a stream writer; counts per
    class in / kept. Usable as a :class:`prc_slam.pipeline.Sink` (``frame(step)``,
    ``close(result)``) or directly (``add(frame)``).

    Parameters
    ----------
    writer : object with ``write(scan, keep, labels)``, ``close()`` and ``format``
        (``data_tools.formats.stream_out.open_stream_writer``)
    config : the filter policy
    keep_labels : label codes; replaces the policy by "keep exactly these classes"
    """

    def __init__(self, writer: Any, config: FilterConfig, keep_labels: Sequence[int] | None = None) -> None:
        self.writer = writer
        self.config = config
        self.keep_labels = None if keep_labels is None else sorted(set(int(c) for c in keep_labels))
        self.n_in = np.zeros(256, np.int64)
        self.n_kept = np.zeros(256, np.int64)
        self.frames = 0
        self.prc_seconds = 0.0
        self.warnings: list[str] = []
        self.n_warnings = 0
        self.worst_collisions = 0.0
        self.organised = False
        self._closed = False

    def add(self, frame: ClassifiedFrame) -> np.ndarray:
        """Filter and write one frame; returns the keep mask (input order)."""
        scan = frame.scan
        labels = np.asarray(frame.point_labels(), dtype=np.uint8)
        points = scan.points()
        if len(points) != len(labels):
            raise ScanError(f"{scan.source}: {len(labels)} labels for {len(points)} input points")
        keep = choose_points(
            points, labels, self.config, one_sided=frame.point_one_sided(), keep_labels=self.keep_labels
        )
        self.writer.write(scan, keep, labels)
        self.n_in += _count(labels)
        self.n_kept += _count(labels[keep])
        self.prc_seconds += frame.seconds
        self.frames += 1
        org = scan.meta.get("organize")
        if isinstance(org, dict):
            self.organised = True
            self.worst_collisions = max(self.worst_collisions, float(org.get("collisions_pct") or 0.0))
            for w in org.get("warnings") or []:
                self.n_warnings += 1
                if len(self.warnings) < 20:
                    self.warnings.append(f"{scan.name}: {w}")
        return keep

    def frame(self, step: Any) -> None:
        """Sink protocol: one :class:`prc_slam.pipeline.PipelineFrame`."""
        self.add(step.frame)

    def close(self, result: Any = None) -> None:
        """Finish the output (idempotent)."""
        if not self._closed:
            self._closed = True
            self.writer.close()

    def metrics(self) -> dict[str, Any]:
        """Counts per class in / kept, the output and the policy (the ``filter`` metrics JSON)."""
        n_in, n_kept = self.n_in, self.n_kept
        present = np.flatnonzero(n_in)
        out: dict[str, Any] = {
            "frames": self.frames,
            "points_in": int(n_in.sum()),
            "points_kept": int(n_kept.sum()),
            "kept_fraction": float(n_kept.sum() / n_in.sum()) if n_in.sum() else None,
            "per_class": {
                L.CODE_TO_NAME.get(int(c), f"code_{c}"): {"in": int(n_in[c]), "kept": int(n_kept[c])} for c in present
            },
            "out": str(getattr(self.writer, "out", "")),
            "out_format": getattr(self.writer, "format", None),
            "keep_labels": None if self.keep_labels is None else [L.CODE_TO_NAME[c] for c in self.keep_labels],
            "policy": None if self.keep_labels is not None else self.config.model_dump(mode="json"),
            "prc_seconds": self.prc_seconds,
        }
        if self.organised:
            out["organize"] = {
                "warnings": self.n_warnings,
                "first_warnings": self.warnings,
                "max_collisions_pct": self.worst_collisions,
            }
        return out
