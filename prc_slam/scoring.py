"""Scorers: pipeline sinks that score a run's labels against the input's ground truth.

:class:`PRCScorer` gives the ``classify`` metrics JSON of DESIGN.md, :class:`OnlineScorer` the
``detect`` one. Both count frames and points themselves and score only frames that carry
reference labels.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from prc_slam import labels as L
from prc_slam.evaluation import ConfusionAccumulator, objects_found
from prc_slam.pipeline import PipelineFrame, PipelineResult

#: Reference classes whose points must not be called noise.
SOLID_CLASSES = [L.GROUND, L.BUILDING, L.VEGETATION, L.TRUNK, L.VEHICLE, L.POLE]


def class_shares(counts: np.ndarray) -> dict[str, dict[str, float]]:
    """``{name: {"points", "share"}}`` of the classes in ``counts`` (points per label code),
    shares of the points with a return (code 0 left out), largest first."""
    returns = int(counts[1:].sum())
    codes = [c for c in np.flatnonzero(counts) if c != L.NO_RETURN]
    codes.sort(key=lambda c: -counts[c])
    return {
        L.CODE_TO_NAME.get(int(c), str(int(c))): {"points": int(counts[c]), "share": float(counts[c]) / returns}
        for c in codes
    }


class PRCScorer:
    """PRC labels against the reference labels of every frame that has them; the points of
    every class in every frame (``classes``), labelled or not."""

    def __init__(self) -> None:
        self.confusion = ConfusionAccumulator()
        self.have_gt = False
        self.counts = np.zeros(256, np.int64)

    def frame(self, step: PipelineFrame) -> None:
        if step.frame.labels is None:
            return
        labels = step.frame.point_labels()
        self.counts += np.bincount(labels, minlength=256)[:256]
        ref = step.scan.reference_labels()
        if ref is None:
            return
        self.have_gt = True
        self.confusion.add(ref, labels)

    def close(self, result: PipelineResult) -> None:
        pass

    def metrics(self, result: PipelineResult) -> dict[str, Any]:
        """The ``classify`` metrics JSON (``per_class`` and ``confusion`` only with ground truth)."""
        out: dict[str, Any] = {
            **result.summary(),
            "seconds": result.prc_seconds,
            "wall_seconds": result.wall_seconds,
            "points_per_s": result.points / result.prc_seconds if result.prc_seconds > 0 else None,
            "classes": class_shares(self.counts),
        }
        if self.have_gt:
            out["per_class"] = self.confusion.per_class()
            out["confusion"] = self.confusion.to_json()
            out["noise_in_solid_classes"] = self.confusion.fraction(SOLID_CLASSES, L.NOISE)
        return out


class OnlineScorer:
    """Online detector labels against the reference, plus vehicles and curb sections found.

    A vehicle is found when at least half of its points are labelled vehicle; a curb section
    (a thin, short object) when at least 30 % of its points are labelled curb. Both shares are in
    the metrics (``objects.<class>.share``)."""

    OBJECT_SHARE: ClassVar[dict[int, float]] = {L.VEHICLE: 0.5, L.CURB: 0.3}
    OBJECT_CODES = tuple(OBJECT_SHARE)

    def __init__(self) -> None:
        self.confusion = ConfusionAccumulator()
        self.have_gt = False
        self.curbs = 0
        self.objects = {code: np.zeros(2, int) for code in self.OBJECT_CODES}  # found, present

    def frame(self, step: PipelineFrame) -> None:
        res = step.online
        if res is None:
            return
        scan = step.scan
        self.curbs += len(res.curb_polylines)
        ref = scan.reference_labels()
        if ref is not None:
            self.have_gt = True
            self.confusion.add(ref, scan.per_point(res.labels))
        if scan.gt_labels is not None and scan.gt_instance is not None:
            for code in self.OBJECT_CODES:
                share = self.OBJECT_SHARE[code]
                found, present = objects_found(scan.gt_labels, scan.gt_instance, res.labels, code, share=share)
                self.objects[code] += np.array([found, present])

    def close(self, result: PipelineResult) -> None:
        pass

    def metrics(self, result: PipelineResult) -> dict[str, Any]:
        """The ``detect`` metrics JSON; ``points_per_s_after_first`` leaves out the first frame,
        which also loads the compiled kernels."""
        seconds, first = result.online_seconds, result.online_seconds_first
        out: dict[str, Any] = {
            **result.summary(),
            "seconds": seconds,
            "seconds_first": first,
            "points_per_s": result.points / seconds if seconds > 0 else None,
            "points_per_s_after_first": (
                (result.points - result.online_points_first) / (seconds - first) if seconds > first else None
            ),
            "curb_polylines_per_frame": self.curbs / max(result.frames, 1),
        }
        if self.have_gt:
            out["per_class"] = self.confusion.per_class()
            out["confusion"] = self.confusion.to_json()
            out["objects"] = {
                L.CODE_TO_NAME[code]: {"found": int(fp[0]), "present": int(fp[1]), "share": self.OBJECT_SHARE[code]}
                for code, fp in self.objects.items()
            }
        return out
