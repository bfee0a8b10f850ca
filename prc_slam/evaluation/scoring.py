"""Scorers: pipeline sinks that score a run's labels against the input's ground truth.

:class:`PRCScorer` gives the ``classify`` metrics JSON of DESIGN.md, :class:`OnlineScorer` the
``detect`` one. Both count frames and points themselves and score only frames that carry
reference labels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from prc_slam import labels as L
from prc_slam.evaluation.metrics import ConfusionAccumulator, objects_found
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


#: range bands (m, horizontal distance from the sensor) of the per-instance scores; the last is open
RANGE_BANDS_M: tuple[tuple[float, float], ...] = ((0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 40.0), (40.0, np.inf))


def band_name(lo: float, hi: float) -> str:
    """``"0-10"``, ..., ``"40+"``: a band's name in tables and in the metrics JSON."""
    return f"{lo:g}+" if not np.isfinite(hi) else f"{lo:g}-{hi:g}"


@dataclass
class InstanceBands:
    """Per-instance and per-point scores of one class by range band (Stamos et al.'s cars).

    An instance of ``code`` in one frame (reference label ``code``, one reference instance id) with at
    least ``min_points`` returns is *present*; it is *found* when at least ``share`` of its returns are
    labelled ``code``. Its range is the horizontal distance from the sensor to the mean of its returns
    in that frame. Point figures go by each return's own horizontal distance: ``recall`` (reference
    returns of ``code`` labelled ``code``), ``precision`` (returns labelled ``code`` whose reference is
    ``code``) and ``vegetation_share`` (reference returns of ``code`` labelled vegetation).
    """

    code: int = L.VEHICLE
    share: float = 0.5
    min_points: int = 20
    bands: tuple[tuple[float, float], ...] = RANGE_BANDS_M
    counts: dict[str, np.ndarray] = field(default_factory=dict)

    KEYS: ClassVar[tuple[str, ...]] = ("present", "found", "points", "hit", "vegetation", "predicted", "true_pred")

    def __post_init__(self) -> None:
        self.counts = {k: np.zeros(len(self.bands), np.int64) for k in self.KEYS}

    def band_of(self, dist: np.ndarray) -> np.ndarray:
        """Band index of each distance (-1: in none)."""
        edges_lo = np.array([b[0] for b in self.bands])
        edges_hi = np.array([b[1] for b in self.bands])
        dist = np.asarray(dist, dtype=np.float64)
        inside = (dist[:, None] >= edges_lo[None]) & (dist[:, None] < edges_hi[None])
        return np.where(inside.any(axis=1), np.argmax(inside, axis=1), -1)

    def add(self, reference: np.ndarray, instance: np.ndarray, predicted: np.ndarray, xyz: np.ndarray) -> None:
        """Score one frame: per-return reference codes, reference instance ids, predicted codes and
        sensor-frame coordinates ``(n, 3)`` (returns only, or every slot with code 0 where none)."""
        reference = np.asarray(reference).ravel()
        predicted = np.asarray(predicted).ravel()
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        if not (len(reference) == len(predicted) == len(xyz) == np.asarray(instance).size):
            raise ValueError(
                f"instance scores: {len(reference)} reference labels, {np.asarray(instance).size} instance ids, "
                f"{len(predicted)} predicted labels and {len(xyz)} points"
            )
        rho = np.hypot(xyz[:, 0], xyz[:, 1])
        nb = len(self.bands)
        is_ref = reference == self.code
        # per-point figures by each return's own range
        b = self.band_of(rho)
        on = b >= 0

        def per_band(mask: np.ndarray) -> np.ndarray:
            return np.bincount(b[mask & on], minlength=nb)[:nb]

        self.counts["points"] += per_band(is_ref)
        self.counts["hit"] += per_band(is_ref & (predicted == self.code))
        self.counts["vegetation"] += per_band(is_ref & (predicted == L.VEGETATION))
        self.counts["predicted"] += per_band(predicted == self.code)
        self.counts["true_pred"] += per_band(is_ref & (predicted == self.code))
        # instances by the range of their mean return
        inst = np.where(is_ref, np.asarray(instance).ravel(), 0).astype(np.int64)
        if not inst.any():
            return
        ids, k = np.unique(inst[is_ref], return_inverse=True)
        total = np.bincount(k, minlength=len(ids))
        hit = np.bincount(k, weights=predicted[is_ref] == self.code, minlength=len(ids))
        mx = np.bincount(k, weights=xyz[is_ref, 0], minlength=len(ids)) / total
        my = np.bincount(k, weights=xyz[is_ref, 1], minlength=len(ids)) / total
        present = (total >= self.min_points) & (ids != 0)
        found = present & (hit >= self.share * total)
        bi = self.band_of(np.hypot(mx, my))
        self.counts["present"] += np.bincount(bi[present & (bi >= 0)], minlength=nb)[:nb]
        self.counts["found"] += np.bincount(bi[found & (bi >= 0)], minlength=nb)[:nb]

    def merge(self, other: InstanceBands) -> None:
        """Add another accumulator's counts (same bands)."""
        for k in self.KEYS:
            self.counts[k] += other.counts[k]

    @staticmethod
    def _ratio(a: int, b: int) -> float | None:
        return float(a) / b if b > 0 else None

    def _row(self, lo: float, hi: float, sel: slice | list[int]) -> dict[str, Any]:
        c = {k: int(np.sum(v[sel])) for k, v in self.counts.items()}
        return {
            "band": band_name(lo, hi),
            "min_m": lo,
            "max_m": hi if np.isfinite(hi) else None,
            "present": c["present"],
            "found": c["found"],
            "found_share": self._ratio(c["found"], c["present"]),
            "points": c["points"],
            "precision": self._ratio(c["true_pred"], c["predicted"]),
            "recall": self._ratio(c["hit"], c["points"]),
            "vegetation_share": self._ratio(c["vegetation"], c["points"]),
        }

    def to_json(self) -> dict[str, Any]:
        """``{"share", "min_points", "bands": [row per band], "within_20": row}``; each row: ``band``,
        ``min_m``, ``max_m`` (None: open), ``present``, ``found``, ``found_share``, ``points``,
        ``precision``, ``recall``, ``vegetation_share`` (None where nothing to divide by)."""
        rows = [self._row(lo, hi, [i]) for i, (lo, hi) in enumerate(self.bands)]
        near = [i for i, (_, hi) in enumerate(self.bands) if hi <= 20.0]
        out: dict[str, Any] = {"share": self.share, "min_points": self.min_points, "bands": rows}
        if near:
            out["within_20"] = self._row(self.bands[near[0]][0], 20.0, near)
        return out


def range_band_rows(by_range: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """Header and rows of the per-band table (console and report) from :meth:`InstanceBands.to_json`."""

    def f(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    header = ["range (m)", "instances found", "found share", "points", "precision", "recall", "labelled vegetation"]
    rows = []
    for r in [*by_range["bands"], *([by_range["within_20"]] if "within_20" in by_range else [])]:
        rows.append(
            [r["band"], f"{r['found']} of {r['present']}", f(r["found_share"]), str(r["points"]), f(r["precision"]),
             f(r["recall"]), f(r["vegetation_share"])]
        )  # fmt: skip
    return header, rows


def range_table(by_range: dict[str, Any], title: str) -> Any:
    """A rich ``Table`` of :func:`range_band_rows` for the console."""
    from rich.table import Table

    header, rows = range_band_rows(by_range)
    table = Table(title=title)
    for i, col in enumerate(header):
        table.add_column(col, justify="left" if i == 0 else "right")
    for r in rows:
        table.add_row(*r)
    return table


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
        self.by_range = InstanceBands(L.VEHICLE, self.OBJECT_SHARE[L.VEHICLE])

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
            self.by_range.add(scan.gt_labels, scan.gt_instance, res.labels, scan.slot_xyz())

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
            if self.by_range.counts["present"].any() or self.by_range.counts["points"].any():
                out["vehicle_by_range"] = self.by_range.to_json()
        return out
