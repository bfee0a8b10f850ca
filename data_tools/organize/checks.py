"""The plausibility checks of every organised sweep, and their reports.

Every sweep is checked (rings found vs expected, share of points that share a slot, empty rows,
occupancy of the range image). Out of range -> a warning logged on ``prc_slam.organize`` and
counted in ``Scan.meta["organize"]`` (:class:`OrganizeReport`); a sweep that cannot be organised
-> :class:`~data_tools.errors.DataError` naming the source. A collapse is never silent.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from data_tools.errors import DataError

log = logging.getLogger("prc_slam.organize")

#: fewer returns than this share of the range image's slots: its rings or columns are implausible
#: (a spinning sweep fills most of them; a camera-FOV crop of 30 deg still fills 8 %)
MIN_OCCUPANCY = 0.03
#: share of points sharing a slot above which a sweep is reported (warning) / refused (error)
WARN_COLLISIONS = 0.12
MAX_COLLISIONS = 0.5


@dataclass
class OrganizeReport:
    """Plausibility figures of one organised sweep (``Scan.meta["organize"]``)."""

    method: str
    rings: int
    expected_rings: int | None
    cols: int
    collisions_pct: float
    empty_rows: int
    nonfinite_points: int
    warnings: list[str] = field(default_factory=list)
    multi_returns: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "rings": int(self.rings),
            "expected_rings": None if self.expected_rings is None else int(self.expected_rings),
            "cols": int(self.cols),
            "collisions_pct": float(self.collisions_pct),
            "empty_rows": int(self.empty_rows),
            "nonfinite_points": int(self.nonfinite_points),
            "multi_returns": int(self.multi_returns),
            "warnings": list(self.warnings),
        }


class OrganizeSummary:
    """The organiser's reports over a run, for the metrics JSON (``"organize"`` key).

    ``add(scan.meta.get("organize"))`` per frame (frames without a report, e.g. from the
    simulator or an organised source, are counted as such); ``as_dict()`` gives
    ``{"frames", "methods", "rings": {min, median, max}, "expected_rings", "cols",
    "collisions_pct": {mean, max}, "empty_rows_max", "nonfinite_points", "warnings",
    "warning_messages"}`` (the first 20 messages)."""

    def __init__(self) -> None:
        self.reports: list[dict[str, Any]] = []
        self.unorganised = 0

    def add(self, report: dict[str, Any] | None) -> None:
        if report is None:
            self.unorganised += 1
        else:
            self.reports.append(report)

    def as_dict(self) -> dict[str, Any]:
        r = self.reports
        if not r:
            return {"frames": 0, "frames_without_report": self.unorganised, "warnings": 0}
        rings = np.array([x["rings"] for x in r])
        coll = np.array([x["collisions_pct"] for x in r])
        messages = [m for x in r for m in x["warnings"]]
        return {
            "frames": len(r),
            "frames_without_report": self.unorganised,
            "methods": sorted({x["method"] for x in r}),
            "rings": {"min": int(rings.min()), "median": float(np.median(rings)), "max": int(rings.max())},
            "expected_rings": r[-1]["expected_rings"],
            "cols": r[-1]["cols"],
            "collisions_pct": {"mean": float(coll.mean()), "max": float(coll.max())},
            "empty_rows_max": int(max(x["empty_rows"] for x in r)),
            "nonfinite_points": int(sum(x["nonfinite_points"] for x in r)),
            "warnings": len(messages),
            "warning_messages": messages[:20],
        }


def check_sweep(
    method: str,
    rows: int,
    cols: int,
    per_row: np.ndarray,
    collisions: int,
    n_ok: int,
    n_bad: int,
    expected: int | None,
    source: str,
    warnings: list[str],
    multi: int = 0,
) -> OrganizeReport:
    """The report of one organised sweep (``rows x cols`` image, ``per_row`` points per row,
    ``n_ok`` returns, ``n_bad`` no-return points, ``expected`` beams when known); what is out of
    range is added to ``warnings`` (which the report keeps) and logged.

    Raises
    ------
    DataError
        When half the points or more share a slot with a point of another firing, or all fell
        in one ring."""
    found = int((per_row > 0).sum())
    empty = int(rows - found)
    # further returns of one firing share their slot by nature: only the others count
    coll = (collisions - multi) / max(n_ok, 1)
    if n_ok > 4 * cols and coll > MAX_COLLISIONS:
        raise DataError(
            f"{source}: cannot organise: {100 * coll:.0f}% of the points share a range-image slot "
            f"({found} rings found, {cols} columns, method {method})"
        )
    if found == 1 and n_ok > 4 * cols:
        raise DataError(f"{source}: cannot organise: all {n_ok} points fell in one ring ({method})")
    if coll > WARN_COLLISIONS:
        warnings.append(
            f"{source}: {100 * coll:.1f}% of the points share a range-image slot with a point of another "
            f"firing (method {method}, {found} rings, {cols} columns)"
        )
    if expected is not None and found < 0.75 * expected:
        warnings.append(f"{source}: {found} rings found, the sensor has {expected}")
    if expected is not None and rows != expected and found >= 0.75 * expected:
        warnings.append(f"{source}: {rows} beams found, the sensor has {expected}")
    if n_ok > 1000 and n_ok < MIN_OCCUPANCY * rows * cols:
        warnings.append(
            f"{source}: only {100 * n_ok / (rows * cols):.1f}% of the {rows} x {cols} range image's slots hold a "
            f"point (method {method}): the rings or the column count are likely wrong"
        )
    if rows and empty > 0.25 * rows:
        warnings.append(f"{source}: {empty} of {rows} rows hold no point")
    for w in warnings:
        log.warning(w)
    return OrganizeReport(
        method, found, expected, cols, 100.0 * collisions / max(n_ok, 1), empty, n_bad, warnings, int(multi)
    )
