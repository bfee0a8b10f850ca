"""Trajectory regression for users' pytest suites.

``assert_trajectory_close`` compares two trajectories and fails with a readable message (where
and how far they diverge). The pytest plugin :mod:`prc_slam.testing.plugin` (registered as an
entry point, active wherever prc_slam is installed) adds a ``trajectory_regression`` fixture that
compares a run against a golden KITTI pose file next to the test and rewrites it with
``pytest --update-golden``.
"""

from __future__ import annotations

import numpy as np

from prc_slam.evaluation import metrics as E


def assert_trajectory_close(estimate: np.ndarray, reference: np.ndarray, ate_tol: float, rpe_tol: float) -> None:
    """Fail unless ``estimate`` follows ``reference`` (both ``(n, 4, 4)``).

    Parameters
    ----------
    ate_tol : float
        Largest allowed ATE RMSE (m) after SE(3) alignment.
    rpe_tol : float
        Largest allowed frame-to-frame relative translation error (m).

    Raises
    ------
    AssertionError
        Naming the failing measure, its value, the frame where the trajectories diverge most
        and the positions there.
    """
    est = np.asarray(estimate, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if est.shape != ref.shape:
        raise AssertionError(f"trajectory lengths differ: {len(est)} estimated poses vs {len(ref)} reference poses")
    if not np.isfinite(est).all():
        bad = int(np.argmax(~np.isfinite(est).all(axis=(1, 2))))
        raise AssertionError(f"estimated pose {bad} is not finite")
    ate = E.ate_rmse(est, ref)
    rot, t, _ = E.umeyama(est[:, :3, 3], ref[:, :3, 3])
    aligned = est[:, :3, 3] @ rot.T + t
    dev = np.linalg.norm(aligned - ref[:, :3, 3], axis=1)
    rel = E.rpe(est, ref)
    problems = []
    if ate > ate_tol:
        i = int(np.argmax(dev))
        problems.append(
            f"ATE RMSE {ate:.4f} m > {ate_tol:.4f} m; largest deviation {dev[i]:.4f} m at frame {i} "
            f"(estimate {np.round(aligned[i], 3).tolist()} vs reference {np.round(ref[i, :3, 3], 3).tolist()}, "
            f"first frame over tolerance: {int(np.argmax(dev > ate_tol))})"
        )
    if len(rel) and rel.max() > rpe_tol:
        j = int(np.argmax(rel))
        problems.append(
            f"relative error {rel[j]:.4f} m > {rpe_tol:.4f} m between frames {j} and {j + 1} "
            f"({int(np.sum(rel > rpe_tol))} of {len(rel)} steps over tolerance)"
        )
    if problems:
        raise AssertionError("trajectories diverge:\n  " + "\n  ".join(problems))
