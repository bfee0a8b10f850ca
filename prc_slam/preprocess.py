"""PRC as a preprocessing step for users who bring their own loop.

:class:`Preprocessor` turns one sweep (an ``(N, 3)`` array with optional per-point times, or a
:class:`~prc_slam.scan.Scan`) into PRC labels for every input point and the points the filter
policy keeps; :class:`PRCKissICP` is a drop-in for KISS-ICP's ``KissICP`` that PRC-filters every
frame before registering it.

This module sits above the core: organising a bare point array uses
:class:`data_tools.organize.Organizer` (imported when first needed).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from prc_slam.config import Config
from prc_slam.filtering import filter_points
from prc_slam.prc import prc_block
from prc_slam.prc.config import PRCConfig
from prc_slam.prc.ground import GroundState
from prc_slam.scan import Scan


@dataclass
class Preprocessed:
    """One sweep after PRC and the filter policy.

    Attributes
    ----------
    points : ndarray of float32, shape (K, 3)
        The kept points, in the order to register them (``order``).
    timestamps : ndarray of float64, shape (K,) or None
        Their times, when the input had times.
    labels : ndarray of uint8, shape (K,)
        Their PRC labels.
    keep : ndarray of bool, shape (N,)
        Which input points were kept.
    order : ndarray of int64, shape (K,)
        Input index of each kept point: input order with the filter's ``representative="first"``,
        else pseudo-random (KISS-ICP keeps the first point of each voxel it meets).
    point_labels : ndarray of uint8, shape (N,)
        The PRC label of every input point, in input order (0 for non-finite input points).
    scan : Scan
        The organised sweep.
    """

    points: np.ndarray
    timestamps: np.ndarray | None
    labels: np.ndarray
    keep: np.ndarray
    order: np.ndarray
    point_labels: np.ndarray
    scan: Scan


class Preprocessor:
    """PRC labels and the filter policy for one sweep at a time.

    Parameters
    ----------
    config : Config or PRCConfig, optional
        The run configuration (its ``prc`` and ``filter`` sections); default: the ``multibeam``
        PRC preset and the default filter policy.
    rows, cols : int, optional
        The sensor's beams and columns per sweep, when known (else estimated from the first sweep
        and kept for the sequence, so every sweep is organised the same way).

    Examples
    --------
    >>> import numpy as np
    >>> from prc_slam import Preprocessor
    >>> pre = Preprocessor()
    >>> out = pre(points, timestamps)  # doctest: +SKIP
    >>> out.points.shape, np.bincount(out.point_labels)  # doctest: +SKIP
    """

    def __init__(
        self, config: Config | PRCConfig | None = None, *, rows: int | None = None, cols: int | None = None
    ) -> None:
        if config is None:
            config = Config(prc=PRCConfig.preset("multibeam"))
        elif isinstance(config, PRCConfig):
            config = Config(prc=config)
        self.config = config
        self.rows, self.cols = rows, cols
        self._organizer: Any = None
        self._ground = GroundState()  # the column ground's plane, carried from sweep to sweep
        self.frames = 0

    def organize(self, points: np.ndarray, timestamps: np.ndarray | None = None, **fields: Any) -> Scan:
        """A bare sweep as an organised :class:`Scan` (ring from ``fields['ring']`` when given)."""
        if self._organizer is None:
            from data_tools.organize import Organizer

            self._organizer = Organizer(rows=self.rows, cols=self.cols)
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] < 3:
            raise ValueError(f"points must be an (N, 3) array, got shape {pts.shape}")
        return self._organizer.scan(
            pts[:, :3], times=timestamps, name=f"{self.frames:06d}", source=f"frame {self.frames}", **fields
        )

    def labels(self, scan: Scan) -> tuple[np.ndarray, np.ndarray]:
        """PRC labels and the one-sided marks per slot of one sweep (a profiler block is
        classified on its own, without the stream's block boundary)."""
        cfg = self.config.prc
        wrap = (not scan.sensor.continuous_rows) if cfg.wrap_columns is None else cfg.wrap_columns
        res = prc_block(scan.ranges, cfg, sensor=scan.sensor, wrap=wrap, ground_state=self._ground)
        return res.labels, res.one_sided

    def __call__(self, frame: np.ndarray | Scan, timestamps: np.ndarray | None = None, **fields: Any) -> Preprocessed:
        """Classify one sweep and apply the filter policy.

        Parameters
        ----------
        frame : ndarray (N, 3) or Scan
        timestamps : ndarray (N,), optional
            Per-point times (s) of a bare sweep.
        **fields
            Per-point fields of a bare sweep passed to the organiser (``ring``, ``intensity``).
        """
        scan = frame if isinstance(frame, Scan) else self.organize(frame, timestamps, **fields)
        self.frames += 1
        slot_labels, one_sided = self.labels(scan)
        point_labels = scan.per_point(slot_labels)
        pts = scan.points()
        times = scan.point_times()
        res = filter_points(pts, point_labels, self.config.filter, scan.per_point(one_sided))
        keep = res.keep
        order = res.kept_in_order  # the order KISS-ICP should meet them in (FilterConfig.representative)
        return Preprocessed(
            points=pts[order],
            timestamps=None if times is None else np.asarray(times)[order],
            labels=point_labels[order],
            keep=keep,
            order=order,
            point_labels=point_labels,
            scan=scan,
        )


def _kiss_icp_base():
    from kiss_icp.kiss_icp import KissICP

    return KissICP


class PRCKissICP(_kiss_icp_base()):  # type: ignore[misc]
    """KISS-ICP's ``KissICP`` with PRC in front: every frame is classified, noise dropped and
    ground thinned by the filter policy, and only the kept points (with their times) registered.

    Same interface as ``kiss_icp.kiss_icp.KissICP``: ``register_frame(frame, timestamps)`` returns
    ``(deskewed kept frame, source points)``; ``last_pose``, ``last_delta`` and ``local_map`` as in
    KISS-ICP. ``last_preprocessed`` holds the last frame's :class:`Preprocessed` (labels of every
    input point).

    Parameters
    ----------
    config : kiss_icp.config.KISSConfig
        KISS-ICP's configuration, as for ``KissICP``.
    prc_config : Config or PRCConfig, optional
        Passed to :class:`Preprocessor`.

    Examples
    --------
    >>> from kiss_icp.config import load_config
    >>> from prc_slam import PRCKissICP
    >>> odometry = PRCKissICP(load_config(None))  # doctest: +SKIP
    >>> odometry.register_frame(points, timestamps)  # doctest: +SKIP
    >>> odometry.last_pose  # doctest: +SKIP
    """

    def __init__(self, config: Any, prc_config: Config | PRCConfig | None = None, **organise: Any) -> None:
        super().__init__(config)
        self.preprocessor = _PreprocessorWithKiss(self.preprocessor, Preprocessor(prc_config, **organise))
        self.last_preprocessed: Preprocessed | None = None

    def register_frame(self, frame: np.ndarray, timestamps: np.ndarray | None):
        pre = self.preprocessor.prc(
            np.asarray(frame), None if timestamps is None or len(timestamps) == 0 else timestamps
        )
        self.last_preprocessed = pre
        stamps = np.zeros(0) if pre.timestamps is None else pre.timestamps
        return super().register_frame(pre.points.astype(np.float64), stamps)


class _PreprocessorWithKiss:
    """KISS-ICP's own preprocessor (range crop, deskew), with the PRC preprocessor beside it."""

    def __init__(self, kiss: Any, prc: Preprocessor) -> None:
        self.kiss, self.prc = kiss, prc

    def preprocess(self, frame: np.ndarray, timestamps: np.ndarray, delta: np.ndarray) -> np.ndarray:
        return self.kiss.preprocess(frame, timestamps, delta)
