"""Checks that a sweep's coordinates are in metres (every threshold downstream is)."""

from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger("prc_slam.readers")

#: a sweep whose median range exceeds this (in the file's units) is not in metres
IMPLAUSIBLE_MEDIAN_RANGE = 1000.0


def implausible_units(xyz: np.ndarray, sample: int = 20000) -> float | None:
    """The median range of a sweep's returns (on a strided sample) when it exceeds
    :data:`IMPLAUSIBLE_MEDIAN_RANGE` (a sweep in millimetres or centimetres: every metre-based
    threshold downstream would be off by 100-1000x), else None."""
    pts = np.asarray(xyz)[:: max(1, len(xyz) // sample)]
    with np.errstate(invalid="ignore", over="ignore"):
        r = np.sqrt(np.sum(np.asarray(pts, np.float64) ** 2, axis=1))
    r = r[np.isfinite(r) & (r > 0)]
    if len(r) < 100:
        return None
    med = float(np.median(r))
    return med if med > IMPLAUSIBLE_MEDIAN_RANGE else None


def off_origin(xyz: np.ndarray, sample: int = 20000) -> tuple[float, float] | None:
    """``(median range, median distance to the points' median)`` when the points lie far from the
    origin compared with their own spread (ten times or more): a sweep in a world or map frame
    (e.g. UTM), not centred on its sensor as every sweep of a spinning or solid-state sensor is."""
    pts = np.asarray(np.asarray(xyz)[:: max(1, len(xyz) // sample)], np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 100:
        return None
    r = float(np.median(np.linalg.norm(pts, axis=1)))
    spread = float(np.median(np.linalg.norm(pts - np.median(pts, axis=0), axis=1)))
    return (r, spread) if r > 10.0 * spread else None


def warn_unless_metres(xyz: np.ndarray, source: str, what: str = "sweeps") -> None:
    """Warn (naming ``source``) when :func:`implausible_units` finds the sweep not in metres, or
    (:func:`off_origin`) not in its sensor's frame."""
    med = implausible_units(xyz)
    away = off_origin(xyz)  # real sweeps: 1.0-1.8 (KITTI, the five multisensor sweeps, Ouster); 75 at 127 m off
    if away is not None:
        log.warning(
            "%s: the returns lie %.0f from the origin but within %.0f of each other: the %s are in a world or "
            "map frame, not their sensor's (the organiser needs each sweep centred on its sensor)",
            source,
            away[0],
            away[1],
            what,
        )
    elif med is not None:
        log.warning(
            "%s: the returns' median range is %.0f: the coordinates are not in metres (millimetres? "
            "centimetres?); every threshold is in metres: convert the %s first",
            source,
            med,
            what,
        )
