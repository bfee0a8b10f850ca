"""The data model: ``Scan`` (one block of the raw stream as a range image) and ``SensorModel``.

A ``Scan`` holds ``ranges[rows, cols]`` in metres, ``0`` for a slot that was emitted but
returned nothing. Columns run along a scan line (the PRC paper's in-slice direction), rows
are successive scan lines (the adjacent-slice direction). Every stage after the source works
on Scans and learns about the sensor only through its ``SensorModel``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numba import njit


class ScanError(ValueError):
    """A scan (or the file it came from) is malformed; the message names the source."""


@njit(cache=True, nogil=True)
def rays_times_ranges(rays, ranges):
    """``rays * ranges[..., None]`` (float32 ``rays[rows, cols, 3]``, ``ranges[rows, cols]``) in one pass: the
    same float32 products, without numpy's broadcast of the ranges over the last axis (three times slower on
    a 64 x 2048 sweep)."""
    rows, cols = ranges.shape
    out = np.empty((rows, cols, 3), np.float32)
    for r in range(rows):
        for c in range(cols):
            v = ranges[r, c]
            out[r, c, 0] = rays[r, c, 0] * v
            out[r, c, 1] = rays[r, c, 1] * v
            out[r, c, 2] = rays[r, c, 2] * v
    return out


@dataclass(frozen=True)
class SensorModel:
    """Geometry of a scan pattern: slot directions and spacing between neighbouring slots.

    Subclasses implement :meth:`directions` and :meth:`neighbour_spacing`.

    Attributes
    ----------
    rows, cols : int
        Range image shape.
    continuous_rows : bool
        True when consecutive blocks continue each other (a profiler: each row is one scan
        line), so the PRC block boundary condition applies; False for spinning sensors whose
        blocks are whole sweeps.
    """

    rows: int
    cols: int
    continuous_rows: bool

    def directions(self) -> np.ndarray:
        """Unit ray direction of every slot in the sensor frame, ``float64[rows, cols, 3]``."""
        raise NotImplementedError

    def neighbour_spacing(self, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Expected spacing (m) between a slot and its in-slice and adjacent-slice neighbours.

        The spacing is measured perpendicular to the ray (normal incidence); callers scale it
        for oblique incidence.

        Parameters
        ----------
        ranges : ndarray, shape (rows, cols)

        Returns
        -------
        in_slice, adjacent_slice : ndarray of float32, shape (rows, cols)
        """
        raise NotImplementedError

    @cached_property
    def unit_rays(self) -> np.ndarray:
        """:meth:`directions` computed once (the model is immutable), ``float32[rows, cols, 3]``."""
        return self.directions().astype(np.float32)

    def to_xyz(self, ranges: np.ndarray) -> np.ndarray:
        """Slot coordinates in the sensor frame, ``float32[rows, cols, 3]`` (zeros for no return)."""
        ranges = np.asarray(ranges, dtype=np.float32)
        if ranges.shape != (self.rows, self.cols):
            raise ScanError(f"ranges shape {ranges.shape} does not match sensor {(self.rows, self.cols)}")
        return rays_times_ranges(self.unit_rays, ranges)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable description (kind and parameters)."""
        raise NotImplementedError


@dataclass(frozen=True)
class SpinningSensor(SensorModel):
    """A spinning multi-beam sensor (Velodyne, Ouster, Hesai): rows are beams, columns azimuth.

    The azimuth of slot ``(r, c)`` is
    ``azimuth0 + direction * 2*pi*(c + 0.5 + column_shift[r]) / cols + beam_azimuth[r]``.

    Attributes
    ----------
    altitude : ndarray, shape (rows,)
        Beam elevation angles (rad), row 0 first.
    beam_azimuth : ndarray, shape (rows,)
        Per-beam azimuth offsets (rad).
    column_shift : ndarray, shape (rows,)
        Per-row column shift (Ouster ``pixel_shift_by_row`` for staggered images, 0 when
        the image is destaggered).
    azimuth0 : float
        Azimuth of the first column (rad).
    direction : int
        +1 when the azimuth grows with the column index, -1 when it falls.
    sweep_period : float
        Duration of one sweep (s).
    mount : ndarray (3, 3), optional
        Rotation from the spin frame (z along the spin axis; altitudes and azimuths are
        measured there) into the frame of the points, when the points are given in a frame
        tilted from the spin axis (a vehicle frame); None: the same frame.
    """

    altitude: np.ndarray = field(default_factory=lambda: np.zeros(0))
    beam_azimuth: np.ndarray = field(default_factory=lambda: np.zeros(0))
    column_shift: np.ndarray = field(default_factory=lambda: np.zeros(0))
    azimuth0: float = 0.0
    direction: int = 1
    sweep_period: float = 0.1
    continuous_rows: bool = False
    mount: np.ndarray | None = None

    @classmethod
    def create(
        cls,
        altitude: np.ndarray,
        cols: int,
        *,
        beam_azimuth: np.ndarray | None = None,
        column_shift: np.ndarray | None = None,
        azimuth0: float = 0.0,
        direction: int = 1,
        sweep_period: float = 0.1,
        mount: np.ndarray | None = None,
    ) -> SpinningSensor:
        """Build a model from per-beam elevation angles (rad) and a column count."""
        altitude = np.asarray(altitude, dtype=np.float64)
        rows = altitude.shape[0]
        zeros = np.zeros(rows)
        return cls(
            rows=rows,
            cols=int(cols),
            continuous_rows=False,
            altitude=altitude,
            beam_azimuth=zeros if beam_azimuth is None else np.asarray(beam_azimuth, float),
            column_shift=zeros if column_shift is None else np.asarray(column_shift, float),
            azimuth0=float(azimuth0),
            direction=int(direction),
            sweep_period=float(sweep_period),
            mount=None if mount is None else np.asarray(mount, dtype=np.float64).reshape(3, 3),
        )

    def azimuth(self) -> np.ndarray:
        """Azimuth (rad) of every slot, ``float64[rows, cols]``."""
        c = np.arange(self.cols, dtype=np.float64)[None, :] + 0.5 + self.column_shift[:, None]
        return self.azimuth0 + self.direction * 2.0 * np.pi * c / self.cols + self.beam_azimuth[:, None]

    @cached_property
    def unit_rays(self) -> np.ndarray:
        """:meth:`directions` as ``float32[rows, cols, 3]``, computed once. The azimuth of a slot is
        a column's angle plus a row's (see the class), so its cosine and sine come from the
        angle-sum formulas over rows + cols sines and cosines instead of rows * cols (within a
        few float64 ulps of :meth:`directions` before the cast)."""
        col = self.azimuth0 + self.direction * 2.0 * np.pi * (np.arange(self.cols, dtype=np.float64) + 0.5) / self.cols
        row = self.direction * 2.0 * np.pi * self.column_shift / self.cols + self.beam_azimuth
        cos_col, sin_col = np.cos(col)[None, :], np.sin(col)[None, :]
        cos_el = np.cos(self.altitude)
        cos_row, sin_row = (cos_el * np.cos(row))[:, None], (cos_el * np.sin(row))[:, None]
        out = np.empty((self.rows, self.cols, 3), np.float32)
        out[..., 0] = cos_row * cos_col - sin_row * sin_col  # cos(el) cos(col + row)
        out[..., 1] = sin_row * cos_col + cos_row * sin_col  # cos(el) sin(col + row)
        out[..., 2] = np.sin(self.altitude)[:, None]
        if self.mount is not None:
            out = (out.astype(np.float64) @ self.mount.T).astype(np.float32)
        return out

    def directions(self) -> np.ndarray:
        az = self.azimuth()
        cos_el = np.cos(self.altitude)[:, None]  # per beam: the trigonometry once per row
        out = np.empty((*az.shape, 3))
        np.multiply(cos_el, np.cos(az), out=out[..., 0])
        np.multiply(cos_el, np.sin(az), out=out[..., 1])
        out[..., 2] = np.sin(self.altitude)[:, None]
        return out if self.mount is None else out @ self.mount.T

    def row_step(self) -> np.ndarray:
        """Angle (rad) between each beam and its nearest neighbouring beam, ``float64[rows]``."""
        if self.rows < 2:
            return np.full(self.rows, np.pi / 180.0)
        gaps = np.abs(np.diff(self.altitude))
        step = np.empty(self.rows)
        step[0], step[-1] = gaps[0], gaps[-1]
        step[1:-1] = np.maximum(gaps[:-1], gaps[1:])
        return step

    def neighbour_spacing(self, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = np.asarray(ranges, dtype=np.float32)
        in_slice = r * np.float32(2.0 * np.pi / self.cols)
        adjacent = r * self.row_step().astype(np.float32)[:, None]
        return in_slice, adjacent

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "spinning",
            "rows": self.rows,
            "cols": self.cols,
            "altitude_deg": np.degrees(self.altitude).round(6).tolist(),
            "beam_azimuth_deg": np.degrees(self.beam_azimuth).round(6).tolist(),
            "column_shift": self.column_shift.tolist(),
            "azimuth0": self.azimuth0,
            "direction": self.direction,
            "sweep_period": self.sweep_period,
            **({} if self.mount is None else {"mount": np.round(self.mount, 9).tolist()}),
        }


@dataclass(frozen=True)
class ProfilerSensor(SensorModel):
    """A 2-D profiler (helical mirror): each row is one mirror revolution of ``cols = M`` points.

    In the scanner frame the scan plane is the y-z plane; the beam angle of column ``h`` is
    ``angle0 + 2*pi*h/M`` measured from +y towards +z. ``mount`` rotates the scanner frame into
    the sensor (platform) frame, e.g. a tilt. Rows are continuous across blocks.

    Attributes
    ----------
    angle0 : float
        Beam angle of column 0 (rad).
    line_rate : float
        Scan lines per second (Hz).
    line_spacing : float
        Expected distance between consecutive scan lines (m), e.g. speed / line_rate; used
        by the adaptive support thresholds.
    mount : ndarray, shape (3, 3)
        Rotation from the scanner frame to the sensor frame.
    """

    angle0: float = 0.0
    line_rate: float = 48.0
    line_spacing: float = 0.17
    mount: np.ndarray = field(default_factory=lambda: np.eye(3))
    continuous_rows: bool = True

    @classmethod
    def create(
        cls,
        rows: int,
        M: int,
        *,
        angle0: float = 0.0,
        line_rate: float = 48.0,
        line_spacing: float = 0.17,
        mount: np.ndarray | None = None,
    ) -> ProfilerSensor:
        """Build a profiler model for blocks of ``rows`` scan lines of ``M`` points."""
        return cls(
            rows=int(rows),
            cols=int(M),
            continuous_rows=True,
            angle0=float(angle0),
            line_rate=float(line_rate),
            line_spacing=float(line_spacing),
            mount=np.eye(3) if mount is None else np.asarray(mount, dtype=np.float64),
        )

    def directions(self) -> np.ndarray:
        theta = self.angle0 + 2.0 * np.pi * np.arange(self.cols) / self.cols
        local = np.stack([np.zeros_like(theta), np.cos(theta), np.sin(theta)], axis=-1)
        d = local @ self.mount.T
        return np.broadcast_to(d[None], (self.rows, self.cols, 3)).copy()

    def neighbour_spacing(self, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = np.asarray(ranges, dtype=np.float32)
        in_slice = r * np.float32(2.0 * np.pi / self.cols)
        adjacent = np.full_like(r, np.float32(self.line_spacing))
        return in_slice, adjacent

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "profiler",
            "rows": self.rows,
            "cols": self.cols,
            "angle0": self.angle0,
            "line_rate": self.line_rate,
            "line_spacing": self.line_spacing,
            "mount": self.mount.tolist(),
        }


def sensor_from_description(desc: dict[str, Any]) -> SensorModel:
    """Inverse of :meth:`SensorModel.describe`."""
    kind = desc.get("kind")
    if kind == "spinning":
        return SpinningSensor.create(
            np.radians(desc["altitude_deg"]),
            desc["cols"],
            beam_azimuth=np.radians(desc["beam_azimuth_deg"]),
            column_shift=np.asarray(desc["column_shift"], float),
            azimuth0=desc["azimuth0"],
            direction=desc["direction"],
            sweep_period=desc["sweep_period"],
            mount=desc.get("mount"),
        )
    if kind == "profiler":
        return ProfilerSensor.create(
            desc["rows"],
            desc["cols"],
            angle0=desc["angle0"],
            line_rate=desc["line_rate"],
            line_spacing=desc["line_spacing"],
            mount=np.asarray(desc["mount"], float),
        )
    raise ScanError(f"unknown sensor kind {kind!r}")


@dataclass
class Scan:
    """One block of the raw LiDAR stream as an organised range image.

    Attributes
    ----------
    ranges : ndarray of float32, shape (rows, cols)
        Range per slot in metres; 0 where the slot returned nothing. NaN on input is
        normalised to 0 and counted in ``meta["nan_ranges"]``.
    sensor : SensorModel
    name : str
        Frame name (the stem used for per-frame outputs, e.g. ``000042``).
    source : str
        Where the scan came from, for error messages.
    intensity : ndarray of float32, shape (rows, cols), optional
    timestamps : ndarray of float64, shape (rows, cols), (cols,) or (rows,), optional
        Acquisition time (s) per slot, per column or per row.
    xyz : ndarray of float32, shape (rows, cols, 3), optional
        Slot coordinates as the source gave them (sensor frame); otherwise computed from
        the sensor model.
    cloud : ndarray of float32, shape (N, 3), optional
        The input point cloud in input order, when the source was an unorganised cloud.
    point_slot : ndarray of int64, shape (N,), optional
        Flat slot index of each input point (several points may share a slot); every input
        point gets exactly the label of its slot back.
    gt_labels : ndarray of uint8, shape (rows, cols), optional
        Reference label code per slot. ``gt_point_labels`` holds them per input point when
        ``point_slot`` is set.
    gt_instance : ndarray of uint32, shape (rows, cols), optional
    gt_pose : ndarray, shape (4, 4), optional
        Ground-truth sensor pose in the world frame.
    """

    ranges: np.ndarray
    sensor: SensorModel
    name: str = "000000"
    source: str = "<memory>"
    intensity: np.ndarray | None = None
    timestamps: np.ndarray | None = None
    xyz: np.ndarray | None = None
    cloud: np.ndarray | None = None
    point_slot: np.ndarray | None = None
    gt_labels: np.ndarray | None = None
    gt_point_labels: np.ndarray | None = None
    gt_instance: np.ndarray | None = None
    gt_pose: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        r = np.asarray(self.ranges)
        if r.ndim != 2:
            raise ScanError(f"{self.source}: ranges must be 2-D (rows, cols), got shape {r.shape}")
        if r.shape != (self.sensor.rows, self.sensor.cols):
            raise ScanError(
                f"{self.source}: ranges shape {r.shape} does not match the sensor model "
                f"{(self.sensor.rows, self.sensor.cols)}"
            )
        r = r.astype(np.float32, copy=True)
        n_nan = 0
        if r.size and not (np.isfinite(lo := r.min()) and lo >= 0 and np.isfinite(r.max())):
            nan = np.isnan(r)  # only when something is off (min/max are the fast check)
            if np.isinf(r).any():
                raise ScanError(f"{self.source}: {int(np.isinf(r).sum())} infinite range values")
            if (r[~nan] < 0).any():
                raise ScanError(f"{self.source}: {int((r[~nan] < 0).sum())} negative range values")
            n_nan = int(nan.sum())
            r[nan] = 0.0
        self.meta.setdefault("nan_ranges", n_nan)
        self.ranges = r
        for name in ("intensity", "gt_labels", "gt_instance"):
            value = getattr(self, name)
            if value is not None and np.shape(value) != r.shape:
                raise ScanError(f"{self.source}: {name} shape {np.shape(value)} != ranges shape {r.shape}")
        if self.xyz is not None and np.shape(self.xyz) != (*r.shape, 3):
            raise ScanError(f"{self.source}: xyz shape {np.shape(self.xyz)} != {(*r.shape, 3)}")
        if (self.cloud is None) != (self.point_slot is None):
            raise ScanError(f"{self.source}: cloud and point_slot must be given together")
        if self.point_slot is not None:
            ps = np.asarray(self.point_slot)
            if ps.shape != (len(self.cloud),):
                raise ScanError(f"{self.source}: point_slot has {ps.shape} entries for {len(self.cloud)} points")
            if len(ps) and (ps.min() < 0 or ps.max() >= r.size):
                raise ScanError(f"{self.source}: point_slot indexes outside the range image")
        if self.timestamps is not None:
            t = np.asarray(self.timestamps, dtype=np.float64)
            if t.shape not in (r.shape, (r.shape[1],), (r.shape[0],)):
                raise ScanError(f"{self.source}: timestamps shape {t.shape} fits neither slots, columns nor rows")
            if not np.isfinite(t).all():
                raise ScanError(f"{self.source}: non-finite timestamps")
            self.timestamps = t

    @property
    def shape(self) -> tuple[int, int]:
        return self.ranges.shape  # type: ignore[return-value]

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask of slots with a return."""
        return self.ranges > 0

    @property
    def n_points(self) -> int:
        """Number of input points (returns, or input cloud points)."""
        return len(self.point_slot) if self.point_slot is not None else int(self.valid.sum())

    def slot_xyz(self) -> np.ndarray:
        """Coordinates per slot, ``float32[rows, cols, 3]``, sensor frame: the measured ones, else
        computed from the ranges once (read-only: several stages of a frame share them)."""
        if self.xyz is not None:
            return self.xyz
        cached = self.__dict__.get("_slot_xyz")
        if cached is None:
            cached = self.sensor.to_xyz(self.ranges)
            cached.flags.writeable = False
            self.__dict__["_slot_xyz"] = cached
        return cached

    def slot_xyz64(self) -> np.ndarray:
        """:meth:`slot_xyz` flattened to ``float64[rows * cols, 3]`` for the numba kernels, made
        once per scan (read-only)."""
        cached = self.__dict__.get("_slot_xyz64")
        if cached is None:
            cached = np.array(self.slot_xyz().reshape(-1, 3), dtype=np.float64)  # a copy
            cached.flags.writeable = False
            self.__dict__["_slot_xyz64"] = cached
        return cached

    def slot_times(self) -> np.ndarray | None:
        """Timestamps broadcast to every slot, ``float64[rows, cols]``, or None."""
        if self.timestamps is None:
            return None
        t = self.timestamps
        if t.shape == self.shape:
            return t
        if t.shape == (self.shape[1],) and t.shape != (self.shape[0],):
            return np.broadcast_to(t[None, :], self.shape)
        if t.shape == (self.shape[0],) and t.shape != (self.shape[1],):
            return np.broadcast_to(t[:, None], self.shape)
        return np.broadcast_to(t[None, :], self.shape)  # square image: per column

    def per_point(self, slot_values: np.ndarray) -> np.ndarray:
        """Values per slot → values per input point, in input order.

        For an unorganised input cloud every point takes the value of its slot; otherwise
        the values of the slots that have a return, in row-major order.
        """
        slot_values = np.asarray(slot_values)
        if slot_values.shape[:2] != self.shape:
            raise ScanError(f"{self.source}: per-slot array of shape {slot_values.shape} for scan {self.shape}")
        if self.point_slot is not None:
            return slot_values.reshape(self.ranges.size, *slot_values.shape[2:])[self.point_slot]
        return slot_values[self.valid]

    def points(self) -> np.ndarray:
        """Input points in the sensor frame, ``float32[N, 3]`` in input order."""
        if self.cloud is not None:
            return self.cloud
        return self.per_point(self.slot_xyz())

    def point_times(self) -> np.ndarray | None:
        """Timestamp per input point, or None."""
        t = self.slot_times()
        return None if t is None else self.per_point(t)

    def reference_labels(self) -> np.ndarray | None:
        """Reference label code per input point, or None without ground truth."""
        if self.gt_point_labels is not None:
            return self.gt_point_labels
        return None if self.gt_labels is None else self.per_point(self.gt_labels)
