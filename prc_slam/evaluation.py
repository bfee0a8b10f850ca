"""Classification scores: confusion matrices and per-class precision / recall / F1.

Trajectory metrics (ATE, RPE, KITTI error) join this module with the odometry stage.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prc_slam import labels as L


class ConfusionAccumulator:
    """Accumulates a confusion matrix over frames (rows: reference code, columns: predicted).

    Slots without a return (code 0) are ignored on either side: there is nothing to score.
    """

    def __init__(self) -> None:
        self.counts = np.zeros((256, 256), dtype=np.int64)

    def add(self, reference: np.ndarray, predicted: np.ndarray) -> None:
        """Add one frame's per-point reference and predicted codes (same length)."""
        reference = np.asarray(reference, dtype=np.uint8).ravel()
        predicted = np.asarray(predicted, dtype=np.uint8).ravel()
        if reference.shape != predicted.shape:
            raise ValueError(f"{reference.size} reference labels for {predicted.size} predictions")
        keep = (reference != L.NO_RETURN) & (predicted != L.NO_RETURN)
        idx = reference[keep].astype(np.int64) * 256 + predicted[keep]
        self.counts += np.bincount(idx, minlength=256 * 256).reshape(256, 256)

    @property
    def codes(self) -> list[int]:
        """Codes present as reference or prediction, ascending."""
        present = (self.counts.sum(axis=0) + self.counts.sum(axis=1)) > 0
        return [int(c) for c in np.flatnonzero(present)]

    def scores(self, code: int) -> dict[str, Any]:
        """Precision, recall, F1 and support (reference count) of one code; None where undefined."""
        tp = int(self.counts[code, code])
        support = int(self.counts[code].sum())
        predicted = int(self.counts[:, code].sum())
        precision = tp / predicted if predicted else None
        recall = tp / support if support else None
        f1 = 2 * precision * recall / (precision + recall) if precision and recall else (0.0 if support else None)
        return {"precision": precision, "recall": recall, "f1": f1, "support": support}

    def per_class(self, codes: list[int] | None = None) -> dict[str, dict[str, Any]]:
        """Scores keyed by class name, for ``codes`` (default: every code present)."""
        return {L.CODE_TO_NAME.get(c, f"code_{c}"): self.scores(c) for c in (codes or self.codes)}

    def fraction(self, reference_codes: list[int], predicted_code: int) -> float:
        """Share of the points of ``reference_codes`` predicted as ``predicted_code``."""
        rows = self.counts[reference_codes]
        total = rows.sum()
        return float(rows[:, predicted_code].sum() / total) if total else 0.0

    def to_json(self) -> dict[str, Any]:
        """``{"labels", "matrix", "counts"}``: rows are reference classes, normalised by their
        totals (the layout of the PRC paper's Table I); ``counts`` holds the raw numbers."""
        codes = self.codes
        sub = self.counts[np.ix_(codes, codes)]
        totals = sub.sum(axis=1, keepdims=True)
        norm = np.divide(sub, totals, out=np.zeros(sub.shape, dtype=float), where=totals > 0)
        return {
            "labels": L.names(codes),
            "matrix": np.round(norm, 6).tolist(),
            "counts": sub.tolist(),
        }
