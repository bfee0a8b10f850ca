"""The ``filter`` stage: every sweep through PRC and the filter policy, the kept points written as a
stream any SLAM system can replay (issue 14, part 3).

Per frame: PRC labels every input point (:func:`prc_slam.pipeline.classify_frames`), the
filter policy (:func:`prc_slam.filtering.filter_points`: drop noise, thin ground, keep the
rest) chooses the points to keep, and a writer emits the kept points with their label in the
input's own kind where possible (``.mcap`` / ROS 2 / ROS 1 bag with the same topic, frame id and
stamps; a PCD folder; KITTI bins). Points without a return (label ``no_return``, e.g. the zero
points of an organised Ouster cloud or NaN points) are never written: they are not measurements.

With ``keep_labels`` the policy is replaced by a plain class selection: every point whose label
is listed is kept (no thinning), every other point is dropped.

This module holds the policy (:func:`choose_points`) and the pipeline sink (:class:`FilterSink`);
the job that opens the input and the writer (``data_tools.stream_out``) is
:func:`prc_slam.jobs.filter.run_filter`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from prc_slam import labels as L
from prc_slam.filtering import FilterConfig, filter_points
from prc_slam.pipeline import ClassifiedFrame
from prc_slam.scan import ScanError


def parse_keep_labels(values: Sequence[str | int] | str | None) -> list[int] | None:
    """Label names or codes (``"ground,building"``, ``["2", "vehicle"]``) → codes; None stays None."""
    if values is None:
        return None
    if isinstance(values, str):
        values = [values]
    codes: list[int] = []
    for v in values:
        for item in str(v).split(","):
            item = item.strip()
            if not item:
                continue
            if item.isdigit():
                code = int(item)
                if code not in L.CODE_TO_NAME:
                    raise ValueError(f"--keep-labels: unknown label code {code}; known: {sorted(L.CODE_TO_NAME)}")
            elif item in L.NAME_TO_CODE:
                code = L.NAME_TO_CODE[item]
            else:
                raise ValueError(f"--keep-labels: unknown label {item!r}; choose from {', '.join(L.NAME_TO_CODE)}")
            codes.append(code)
    if not codes:
        raise ValueError("--keep-labels names no label")
    return sorted(set(codes))


def choose_points(
    points: np.ndarray,
    labels: np.ndarray,
    config: FilterConfig,
    *,
    one_sided: np.ndarray | None = None,
    keep_labels: Sequence[int] | None = None,
) -> np.ndarray:
    """Mask of the points written to the filtered stream (input order).

    The filter policy of ``config`` (or, with ``keep_labels``, the listed classes only); points
    labelled ``no_return`` or with non-finite coordinates are never kept.
    """
    points = np.asarray(points)
    labels = np.asarray(labels, dtype=np.uint8)
    finite = np.isfinite(points).all(axis=1)
    if keep_labels is not None:
        keep = np.isin(labels, np.asarray(list(keep_labels), dtype=np.uint8))
    else:
        policy = config.model_copy(update={"drop": sorted(set(config.drop) | {L.NO_RETURN})})
        safe = np.where(finite[:, None], points, 0.0)
        keep = filter_points(safe, labels, policy, one_sided).keep
    return keep & finite & (labels != L.NO_RETURN)


def _count(labels: np.ndarray) -> np.ndarray:
    return np.bincount(np.asarray(labels, dtype=np.uint8), minlength=256)


class FilterSink:
    """Filters every classified frame and hands the kept points to a stream writer; counts per
    class in / kept. Usable as a :class:`prc_slam.pipeline.Sink` (``frame(step)``,
    ``close(result)``) or directly (``add(frame)``).

    Parameters
    ----------
    writer : object with ``write(scan, keep, labels)``, ``close()`` and ``format``
        (``data_tools.stream_out.open_stream_writer``)
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
