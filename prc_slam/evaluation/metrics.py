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


def objects_found(
    reference: np.ndarray,
    instance: np.ndarray,
    predicted: np.ndarray,
    code: int,
    min_points: int = 20,
    share: float = 0.3,
) -> tuple[int, int]:
    """Object-level counts of one class.

    Instances of ``code`` (reference label and instance id per point) with at least
    ``min_points`` points are present; those with at least ``share`` of their points predicted
    as ``code`` are found.

    Returns
    -------
    found, present : int
    """
    reference = np.asarray(reference).ravel()
    inst = np.where(reference == code, np.asarray(instance).ravel(), 0).astype(np.int64)
    total = np.bincount(inst, minlength=1)
    hit = np.bincount(inst, weights=np.asarray(predicted).ravel() == code, minlength=len(total))
    present = total >= min_points
    present[0] = False
    return int(np.sum(present & (hit >= share * total))), int(present.sum())


# ---- trajectories ------------------------------------------------------------------------


def _check_trajectories(estimate: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    est = np.asarray(estimate, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if est.shape != ref.shape or est.ndim != 3 or est.shape[1:] != (4, 4):
        raise ValueError(f"trajectories must both be (n, 4, 4), got {est.shape} and {ref.shape}")
    if not (np.isfinite(est).all() and np.isfinite(ref).all()):
        raise ValueError("trajectories contain non-finite values")
    return est, ref


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity ``target ≈ s R source + t`` (Umeyama 1991). Returns R, t, s."""
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    xs, xt = source - mu_s, target - mu_t
    cov = xt.T @ xs / len(source)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rot = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / xs.var(axis=0).sum()) if with_scale else 1.0
    return rot, mu_t - scale * rot @ mu_s, scale


def ate_rmse(estimate: np.ndarray, reference: np.ndarray) -> float:
    """Absolute trajectory error (m, RMSE of positions) after SE(3) Umeyama alignment."""
    est, ref = _check_trajectories(estimate, reference)
    p, q = est[:, :3, 3], ref[:, :3, 3]
    rot, t, _ = umeyama(p, q)
    return float(np.sqrt(np.mean(np.sum((p @ rot.T + t - q) ** 2, axis=1))))


def rpe(estimate: np.ndarray, reference: np.ndarray, delta: int = 1) -> np.ndarray:
    """Relative pose error per frame pair ``(i, i + delta)``: translation error norms (m)."""
    est, ref = _check_trajectories(estimate, reference)
    if len(est) <= delta:
        return np.zeros(0)
    d_est = np.linalg.inv(est[:-delta]) @ est[delta:]
    d_ref = np.linalg.inv(ref[:-delta]) @ ref[delta:]
    err = np.linalg.inv(d_ref) @ d_est
    return np.linalg.norm(err[:, :3, 3], axis=1)


KITTI_LENGTHS = (100, 200, 300, 400, 500, 600, 700, 800)


def kitti_errors(
    estimate: np.ndarray, reference: np.ndarray, lengths: tuple[float, ...] = KITTI_LENGTHS, step: int = 10
) -> tuple[float | None, float | None]:
    """KITTI odometry error as the devkit computes it: for every ``step``-th first frame and each
    segment length, the relative pose error over the first sub-sequence at least that long,
    translation in percent of the length and rotation in degrees per metre, averaged.

    Returns ``(None, None)`` when the trajectory is shorter than the shortest length.
    """
    est, ref = _check_trajectories(estimate, reference)
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref[:, :3, 3], axis=0), axis=1))])
    t_err, r_err = [], []
    for first in range(0, len(ref), step):
        for length in lengths:
            last = int(np.searchsorted(dist, dist[first] + length))
            if last >= len(ref):
                continue
            d_ref = np.linalg.inv(ref[first]) @ ref[last]
            d_est = np.linalg.inv(est[first]) @ est[last]
            e = np.linalg.inv(d_est) @ d_ref
            t_err.append(np.linalg.norm(e[:3, 3]) / length)
            r_err.append(np.arccos(np.clip((np.trace(e[:3, :3]) - 1) / 2, -1, 1)) / length)
    if not t_err:
        return None, None
    return float(np.mean(t_err) * 100.0), float(np.degrees(np.mean(r_err)))
