"""Classify a whole input with PRC: labels files, LAS, metrics JSON (the ``classify`` job)."""

from __future__ import annotations

import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from prc_slam import labels as L
from prc_slam.prc.config import PRCConfig
from prc_slam.evaluation import ConfusionAccumulator
from prc_slam.pipeline import classify_frames
from prc_slam.prc.algorithm import warm_up
from prc_slam.scan import Scan

#: Reference classes whose points must not be called noise (issue 2 acceptance).
SOLID_CLASSES = [L.GROUND, L.BUILDING, L.VEGETATION, L.TRUNK, L.VEHICLE, L.POLE]


def run_classification(
    scans: Iterable[Scan],
    config: PRCConfig,
    *,
    labels_out: Path | None = None,
    label_writer=None,
    on_frame=None,
) -> dict[str, Any]:
    """Run PRC over ``scans``; write per-frame label files when asked; score against ground truth.

    Parameters
    ----------
    label_writer : callable(path, codes), optional
        Writes one ``.label`` file (injected so the core does not import the writers).
    on_frame : callable(ClassifiedFrame), optional
        Called for every classified frame (progress, LAS collection).

    Returns
    -------
    metrics : dict
        The ``classify`` metrics JSON of DESIGN.md.
    """
    confusion = ConfusionAccumulator()
    frames = points = 0
    prc_seconds = 0.0
    have_gt = False
    warm_up()
    t_start = time.perf_counter()
    for frame in classify_frames(scans, config):
        frames += 1
        points += frame.scan.n_points
        prc_seconds += frame.seconds
        codes = frame.point_labels()
        if labels_out is not None and label_writer is not None:
            label_writer(labels_out / f"{frame.scan.name}.label", codes)
        ref = frame.scan.reference_labels()
        if ref is not None:
            have_gt = True
            confusion.add(ref, codes)
        if on_frame is not None:
            on_frame(frame)
    metrics: dict[str, Any] = {
        "frames": frames,
        "points": points,
        "seconds": prc_seconds,
        "wall_seconds": time.perf_counter() - t_start,
        "points_per_s": points / prc_seconds if prc_seconds > 0 else None,
    }
    if have_gt:
        metrics["per_class"] = confusion.per_class()
        metrics["confusion"] = confusion.to_json()
        metrics["noise_in_solid_classes"] = confusion.fraction(SOLID_CLASSES, L.NOISE)
    return metrics
