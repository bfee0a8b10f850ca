"""The tools users pick instead of PRC, behind one small interface: per-point masks in input order.

* :func:`statistical_outlier_keep`: Open3D's statistical outlier removal (SOR,
  ``PointCloud.remove_statistical_outlier``): a point is kept when its mean distance to its
  ``nb_neighbors`` nearest neighbours is at most the cloud's mean of that figure plus
  ``std_ratio`` standard deviations.
* :func:`radius_outlier_keep`: Open3D's radius outlier removal (ROR,
  ``PointCloud.remove_radius_outlier``): a point is kept when at least ``min_points`` other
  points lie within ``radius`` (Open3D's ``nb_points``; its count includes the point itself and
  must exceed ``nb_points``, measured in ``tests/test_peers.py``).
* :func:`patchwork_ground`: Patchwork++ ground segmentation (Lee et al., RA-L 2022,
  ``pypatchworkpp``); :class:`PatchworkGround` keeps one estimator over a sequence, as
  Patchwork++ is meant to run (its adaptive elevation and flatness thresholds learn from past
  frames).

Each returns a ``bool[N]`` mask, one entry per input point, in input order, and raises
:class:`PeerUnavailable` (with the install command) when its package is missing. Patchwork++
reports ground as indices into the cloud it was given (``getGroundIndices``); together with
``getNongroundIndices`` they cover every input point exactly once, which
:class:`PatchworkGround` checks on every call rather than trusts.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np

__all__ = [
    "PatchworkGround",
    "PeerUnavailable",
    "patchwork_ground",
    "radius_outlier_keep",
    "statistical_outlier_keep",
]

_PEERS_HINT = "install the optional peers with `pip install prc-slam[peers]` (or `make test`)"


class PeerUnavailable(RuntimeError):
    """A peer tool's package is not installed (the message says how to install it)."""


def _open3d() -> Any:
    try:
        import open3d
    except ImportError as exc:
        raise PeerUnavailable(f"Open3D is not installed ({exc}); `pip install open3d-cpu`") from exc
    return open3d


def _pypatchworkpp() -> Any:
    try:
        import pypatchworkpp
    except ImportError as exc:
        raise PeerUnavailable(f"Patchwork++ (pypatchworkpp) is not installed ({exc}); {_PEERS_HINT}") from exc
    return pypatchworkpp


def _as_xyz(points: np.ndarray, name: str) -> np.ndarray:
    """``float64[N, 3]`` copy of the first three columns; a clear error for anything else."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"{name}: points must have shape (N, 3) or (N, >3), got {pts.shape}")
    xyz = np.ascontiguousarray(pts[:, :3], dtype=np.float64)
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        raise ValueError(f"{name}: {int(bad.sum())} of {len(xyz)} points have non-finite coordinates")
    return xyz


def _kept_mask(n: int, kept: list[int]) -> np.ndarray:
    keep = np.zeros(n, dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    return keep


def statistical_outlier_keep(points: np.ndarray, nb_neighbors: int = 20, std_ratio: float = 2.0) -> np.ndarray:
    """Open3D statistical outlier removal; ``True`` for the points it keeps.

    Parameters
    ----------
    points : float array (N, >=3)
        Only the first three columns are used.
    nb_neighbors, std_ratio
        Open3D's parameters (its defaults in the documentation examples: 20, 2.0).

    Returns
    -------
    bool (N,)
    """
    if nb_neighbors < 1 or std_ratio <= 0:
        raise ValueError(f"SOR needs nb_neighbors >= 1 and std_ratio > 0, got {nb_neighbors}, {std_ratio}")
    xyz = _as_xyz(points, "statistical_outlier_keep")
    if len(xyz) == 0:
        return np.zeros(0, dtype=bool)
    o3d = _open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    _, kept = cloud.remove_statistical_outlier(nb_neighbors=int(nb_neighbors), std_ratio=float(std_ratio))
    return _kept_mask(len(xyz), kept)


def radius_outlier_keep(points: np.ndarray, radius: float = 0.5, min_points: int = 2) -> np.ndarray:
    """Open3D radius outlier removal; ``True`` for points with at least ``min_points`` other
    points within ``radius`` (m).

    Returns
    -------
    bool (N,)
    """
    if radius <= 0 or min_points < 1:
        raise ValueError(f"ROR needs radius > 0 and min_points >= 1, got {radius}, {min_points}")
    xyz = _as_xyz(points, "radius_outlier_keep")
    if len(xyz) == 0:
        return np.zeros(0, dtype=bool)
    o3d = _open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    _, kept = cloud.remove_radius_outlier(nb_points=int(min_points), radius=float(radius))
    return _kept_mask(len(xyz), kept)


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence C++ ``std::cout`` (Patchwork++ prints on construction and when it lacks intensity)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # captured stdout (pytest, notebooks): nothing to do
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


class PatchworkGround:
    """Patchwork++ over a sequence of sweeps (one estimator, so its adaptive thresholds carry over).

    Parameters
    ----------
    sensor_height : float, optional
        Height of the sensor above the ground (m); Patchwork++'s default is KITTI's 1.723 m.
    **params
        Any other attribute of ``pypatchworkpp.Parameters`` (``max_range``, ``min_range``, ...).

    Without intensity (``points`` with three columns) the reflected-noise removal (RNR) that
    needs it is switched off, which is what Patchwork++ does anyway after printing a warning.
    """

    def __init__(self, sensor_height: float | None = None, **params: object) -> None:
        pw = _pypatchworkpp()
        self._params = pw.Parameters()
        self._params.verbose = False
        if sensor_height is not None:
            self._params.sensor_height = float(sensor_height)
        for key, value in params.items():
            if not hasattr(self._params, key):
                raise ValueError(f"unknown Patchwork++ parameter {key!r}")
            setattr(self._params, key, value)
        self._module = pw
        self._estimators: dict[bool, Any] = {}

    def _estimator(self, with_intensity: bool) -> Any:
        if with_intensity not in self._estimators:
            params = self._params
            if not with_intensity:
                params = self._module.Parameters()
                for key in dir(self._params):
                    if not key.startswith("_"):
                        setattr(params, key, getattr(self._params, key))
                params.enable_RNR = False
            with _quiet_stdout():
                self._estimators[with_intensity] = self._module.patchworkpp(params)
        return self._estimators[with_intensity]

    def __call__(self, points: np.ndarray, intensity: np.ndarray | None = None) -> np.ndarray:
        """Ground mask of one sweep, ``bool[N]`` in input order.

        Parameters
        ----------
        points : float array (N, 3) or (N, 4)
            xyz in the sensor frame (z up); a fourth column is taken as intensity.
        intensity : float array (N,), optional
            Overrides the fourth column.
        """
        xyz = _as_xyz(points, "patchwork_ground").astype(np.float32)
        n = len(xyz)
        if n == 0:
            return np.zeros(0, dtype=bool)
        pts = np.asarray(points)
        if intensity is None and pts.shape[1] >= 4:
            intensity = pts[:, 3]
        if intensity is not None:
            intensity = np.asarray(intensity, dtype=np.float32).ravel()
            if intensity.shape != (n,) or not np.isfinite(intensity).all():
                raise ValueError(f"patchwork_ground: intensity must be {n} finite values, got {intensity.shape}")
            cloud = np.ascontiguousarray(np.column_stack([xyz, intensity]), dtype=np.float32)
        else:
            cloud = xyz
        est = self._estimator(intensity is not None)
        with _quiet_stdout():
            est.estimateGround(cloud)
        ground_idx = np.asarray(est.getGroundIndices(), dtype=np.int64).ravel()
        other_idx = np.asarray(est.getNongroundIndices(), dtype=np.int64).ravel()
        seen = np.zeros(n, dtype=np.int64)
        if len(ground_idx) and (ground_idx.min() < 0 or ground_idx.max() >= n):
            raise RuntimeError("Patchwork++ returned ground indices outside the input cloud")
        if len(other_idx) and (other_idx.min() < 0 or other_idx.max() >= n):
            raise RuntimeError("Patchwork++ returned non-ground indices outside the input cloud")
        np.add.at(seen, ground_idx, 1)
        np.add.at(seen, other_idx, 1)
        if not (seen == 1).all():
            raise RuntimeError(
                f"Patchwork++ did not report every input point exactly once ({int((seen == 0).sum())} missing, "
                f"{int((seen > 1).sum())} repeated); its index mapping changed with this version"
            )
        ground = np.zeros(n, dtype=bool)
        ground[ground_idx] = True
        return ground


def patchwork_ground(points: np.ndarray, sensor_height: float | None = None, **params: object) -> np.ndarray:
    """Patchwork++ ground mask of one sweep on its own (a fresh estimator), ``bool[N]`` in input
    order. For a sequence keep one :class:`PatchworkGround`."""
    return PatchworkGround(sensor_height, **params)(points)
