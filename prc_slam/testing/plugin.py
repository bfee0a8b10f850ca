"""pytest plugin: ``trajectory_regression`` fixture and ``--update-golden``.

Usage in a test::

    def test_my_drive(trajectory_regression):
        poses = run_my_odometry()          # (n, 4, 4)
        trajectory_regression.check(poses, ate_tol=0.05, rpe_tol=0.05)

The golden file is ``golden/<test name>.txt`` (KITTI format) beside the test module. A missing
golden file fails with instructions; ``pytest --update-golden`` writes it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prc_slam.testing import assert_trajectory_close


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--update-golden",
        action="store_true",
        default=False,
        help="rewrite golden trajectory files instead of comparing against them",
    )


class TrajectoryRegression:
    """Compares trajectories with golden KITTI pose files."""

    def __init__(self, directory: Path, name: str, update: bool) -> None:
        self.directory, self.name, self.update = directory, name, update

    def path(self, suffix: str = "") -> Path:
        return self.directory / f"{self.name}{suffix}.txt"

    def check(self, poses: np.ndarray, ate_tol: float, rpe_tol: float, suffix: str = "") -> None:
        """Compare ``poses`` with the golden file (or write it under ``--update-golden``)."""
        poses = np.asarray(poses, dtype=np.float64)
        path = self.path(suffix)
        if self.update:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.savetxt(path, poses[:, :3, :].reshape(len(poses), 12), fmt="%.9e")
            return
        if not path.is_file():
            pytest.fail(f"golden trajectory {path} does not exist; run pytest with --update-golden to create it")
        data = np.loadtxt(path, ndmin=2)
        golden = np.tile(np.eye(4), (len(data), 1, 1))
        golden[:, :3, :] = data.reshape(-1, 3, 4)
        try:
            assert_trajectory_close(poses, golden, ate_tol, rpe_tol)
        except AssertionError as exc:
            raise AssertionError(f"{path}: {exc}") from None


@pytest.fixture
def trajectory_regression(request: pytest.FixtureRequest) -> TrajectoryRegression:
    """Golden-trajectory comparison for the requesting test."""
    name = request.node.name.replace("[", "_").replace("]", "").replace("/", "_")
    return TrajectoryRegression(request.path.parent / "golden", name, request.config.getoption("--update-golden"))
