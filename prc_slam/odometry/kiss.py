"""Adapter around ``kiss_icp.kiss_icp.KissICP`` with the same defaults as KISS-ICP.

KISS-ICP's ``KISSConfig`` is a pydantic-settings model that reads ``kiss_icp_*`` environment
variables; the adapter builds it with every section given explicitly and those variables
hidden, so runs do not depend on the caller's shell. ``voxel_size`` defaults to
``max_range / 100`` as in KISS-ICP's own ``load_config``.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class OdometryConfig(BaseModel):
    """KISS-ICP parameters (KISS-ICP 1.x defaults)."""

    model_config = ConfigDict(extra="forbid")

    max_range: float = Field(100.0, gt=0)
    min_range: float = Field(0.0, ge=0)
    deskew: bool = True
    voxel_size: float | None = Field(None, gt=0, description="default: max_range / 100")
    max_points_per_voxel: int = Field(20, ge=1)
    initial_threshold: float = Field(2.0, gt=0)
    min_motion_th: float = Field(0.1, ge=0)
    max_num_iterations: int = Field(500, ge=1)
    convergence_criterion: float = Field(1e-4, gt=0)
    max_num_threads: int = Field(0, ge=0, description="0: automatic")


@contextmanager
def _without_kiss_env():
    saved = {k: os.environ.pop(k) for k in [k for k in os.environ if k.lower().startswith("kiss_icp_")]}
    try:
        yield
    finally:
        os.environ.update(saved)


def kiss_config(config: OdometryConfig):
    """The ``KISSConfig`` for ``config``, independent of ``kiss_icp_*`` environment variables."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig

    with _without_kiss_env():
        return KISSConfig(
            out_dir="/dev/null",
            data=DataConfig(max_range=config.max_range, min_range=config.min_range, deskew=config.deskew),
            mapping=MappingConfig(
                voxel_size=config.voxel_size if config.voxel_size is not None else config.max_range / 100.0,
                max_points_per_voxel=config.max_points_per_voxel,
            ),
            registration=RegistrationConfig(
                max_num_iterations=config.max_num_iterations,
                convergence_criterion=config.convergence_criterion,
                max_num_threads=config.max_num_threads,
            ),
            adaptive_threshold=AdaptiveThresholdConfig(
                initial_threshold=config.initial_threshold, min_motion_th=config.min_motion_th
            ),
        )


def deskew_stamps(times: np.ndarray | None, n: int) -> np.ndarray:
    """Per-point times normalised to [0, 1] over the frame for KISS-ICP's deskewing; an empty
    array (KISS-ICP's "do not deskew") without times for every point."""
    if times is None or len(times) != n or n == 0:
        return np.zeros(0)
    t = np.asarray(times, dtype=np.float64)
    span = float(t.max() - t.min())
    return (t - t.min()) / span if span > 0 else np.full(n, 0.5)


class KissOdometry:
    """Frame-to-map odometry with KISS-ICP; poses start at the identity.

    Parameters
    ----------
    config : OdometryConfig
    """

    def __init__(self, config: OdometryConfig | None = None) -> None:
        from kiss_icp.kiss_icp import KissICP

        self.config = config or OdometryConfig()
        self.kiss = KissICP(kiss_config(self.config))
        self.poses: list[np.ndarray] = []

    def register(
        self, points: np.ndarray, times: np.ndarray | None = None, labels: np.ndarray | None = None
    ) -> np.ndarray:
        """Register one frame and return its pose (4x4, world = first frame).

        Parameters
        ----------
        points : float (N, 3)
            Sensor-frame points, not modified.
        times : float (N,), optional
            Acquisition time per point (s); normalised to [0, 1] over the frame for KISS-ICP's
            deskewing. Without times (or with ``deskew`` off) the frame is not deskewed.
        labels : ignored
            (The class-aware odometry's signature.)
        """
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got {pts.shape}")
        self.kiss.register_frame(pts, deskew_stamps(times, len(pts)))
        pose = self.kiss.last_pose.copy()
        self.poses.append(pose)
        return pose

    def local_map_points(self) -> np.ndarray:
        """Points of KISS-ICP's voxel map (world frame = first frame), ``float64[M, 3]``."""
        return np.asarray(self.kiss.local_map.point_cloud())

    @property
    def threshold(self) -> float:
        """KISS-ICP's current adaptive correspondence threshold (sigma)."""
        return float(self.kiss.adaptive_threshold.get_threshold())
