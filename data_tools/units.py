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


def warn_unless_metres(xyz: np.ndarray, source: str, what: str = "sweeps") -> None:
    """Warn (naming ``source``) when :func:`implausible_units` finds the sweep not in metres."""
    med = implausible_units(xyz)
    if med is not None:
        log.warning(
            "%s: the returns' median range is %.0f: the coordinates are not in metres (millimetres? "
            "centimetres?); every threshold is in metres: convert the %s first",
            source,
            med,
            what,
        )
