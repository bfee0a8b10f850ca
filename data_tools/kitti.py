"""KITTI odometry / SemanticKITTI directories: bins, labels, poses, calib, times.

The Velodyne bins hold the points of one sweep ring by ring (one laser after another,
azimuth increasing within a ring), no-return points dropped. :func:`unfold_scan` rebuilds
the organised 64-row range image by *scan unfolding*: a new ring starts where the azimuth
crosses from negative to non-negative after having wrapped through ±pi; columns are azimuth
bins. Every input point keeps its slot index, so labels computed on the image map back to
every input point in input order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from data_tools.datasets import SequenceBase
from data_tools.errors import DataError
from prc_slam import labels as L
from prc_slam.scan import Scan, SpinningSensor

HDL64_ROWS = 64
HDL64_COLS = 2048
SWEEP_PERIOD = 0.1


def read_velodyne_bin(path: str | Path) -> np.ndarray:
    """Read a KITTI ``.bin`` as ``float32[N, 4]`` (x, y, z, remission)."""
    path = Path(path)
    try:
        raw = np.fromfile(path, dtype=np.float32)
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    if raw.size % 4:
        raise DataError(f"{path}: truncated: {path.stat().st_size} bytes is not a whole number of 16-byte points")
    pts = raw.reshape(-1, 4)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise DataError(
            f"{path}: {int(bad.sum())} points with NaN or infinite values (first at index {int(np.argmax(bad))})"
        )
    return pts


def read_label_file(path: str | Path, n_points: int | None = None) -> np.ndarray:
    """Read a SemanticKITTI ``.label`` file (``uint32[N]``), checking the count if given."""
    path = Path(path)
    size = path.stat().st_size
    if size % 4:
        raise DataError(f"{path}: truncated: {size} bytes is not a whole number of uint32 labels")
    lab = np.fromfile(path, dtype=np.uint32)
    if n_points is not None and lab.size != n_points:
        raise DataError(f"{path}: {lab.size} labels for {n_points} points")
    return lab


def read_calib_tr(path: str | Path) -> np.ndarray:
    """The ``Tr`` entry of a KITTI ``calib.txt`` (Velodyne → camera 0) as a 4x4 matrix."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: calib.txt is missing (needed to turn camera poses into LiDAR poses)")
    for line in path.read_text().splitlines():
        key, _, rest = line.partition(":")
        if key.strip() == "Tr":
            vals = rest.split()
            if len(vals) != 12:
                raise DataError(f"{path}: Tr has {len(vals)} values, expected 12")
            try:
                m = np.array([float(v) for v in vals]).reshape(3, 4)
            except ValueError as exc:
                raise DataError(f"{path}: Tr is not numeric: {exc}") from exc
            return np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    raise DataError(f"{path}: no 'Tr:' line")


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file (one row-major 3x4 matrix per line) as ``float64[n, 4, 4]``."""
    path = Path(path)
    try:
        data = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read KITTI poses: {exc}") from exc
    if data.size == 0:
        return np.zeros((0, 4, 4))
    if data.shape[1] != 12:
        raise DataError(f"{path}: {data.shape[1]} values per line, expected 12 (3x4 row-major)")
    if not np.isfinite(data).all():
        raise DataError(f"{path}: non-finite values")
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    poses[:, :3, :] = data.reshape(-1, 3, 4)
    return poses


def read_times(path: str | Path) -> np.ndarray:
    """Read ``times.txt`` (one time in seconds per line), checking monotonicity."""
    path = Path(path)
    try:
        t = np.loadtxt(path, ndmin=1)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read times: {exc}") from exc
    if not np.isfinite(t).all():
        raise DataError(f"{path}: non-finite times")
    if (np.diff(t) <= 0).any():
        raise DataError(
            f"{path}: times are not strictly increasing (first at line {int(np.argmax(np.diff(t) <= 0)) + 2})"
        )
    return t


def ring_index(points: np.ndarray, max_rings: int = HDL64_ROWS, source: str = "<memory>") -> np.ndarray:
    """Ring of each point by scan unfolding.

    A ring ends where the azimuth crosses from negative to non-negative after the ring has
    wrapped through ±pi (which ignores the jitter of single points around azimuth 0 or pi).
    """
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    yaw = np.arctan2(points[:, 1], points[:, 0])
    d = np.diff(yaw)
    starts = np.flatnonzero((yaw[:-1] < 0) & (yaw[1:] >= 0) & (d < np.pi)) + 1
    wraps = np.flatnonzero(d < -np.pi) + 1
    # keep a start only if a ±pi wrap happened since the previous kept start
    kept = []
    last = 0
    for s in starts:  # one iteration per ring boundary candidate, not per point
        j = np.searchsorted(wraps, last, side="right")
        if j < len(wraps) and wraps[j] < s:
            kept.append(s)
            last = s
    ring = np.zeros(n, dtype=np.int64)
    ring[np.asarray(kept, dtype=np.int64)] = 1
    ring = np.cumsum(ring)
    if ring[-1] >= max_rings:
        raise DataError(f"{source}: scan unfolding found {ring[-1] + 1} rings, more than the sensor's {max_rings}")
    return ring


@dataclass
class UnfoldedScan:
    """Result of :func:`unfold_scan`."""

    ranges: np.ndarray
    point_slot: np.ndarray
    representative: np.ndarray
    altitude: np.ndarray
    collisions: int


def unfold_scan(
    points: np.ndarray, rows: int = HDL64_ROWS, cols: int = HDL64_COLS, source: str = "<memory>"
) -> UnfoldedScan:
    """Organise an unordered-looking KITTI sweep into a ``rows x cols`` range image.

    Returns the range image, each point's flat slot, the representative point of each slot
    (-1 if empty; where several points fall into one slot the nearest is shown to PRC and
    the others take its label) and per-ring elevation angles (median of the ring's points,
    interpolated for empty rings).
    """
    xyz = points[:, :3].astype(np.float64)
    ring = ring_index(xyz, rows, source)
    yaw = np.arctan2(xyz[:, 1], xyz[:, 0]) % (2.0 * np.pi)
    col = np.minimum((yaw * (cols / (2.0 * np.pi))).astype(np.int64), cols - 1)
    slot = ring * cols + col
    rng = np.linalg.norm(xyz, axis=1)
    ranges = np.zeros(rows * cols, dtype=np.float32)
    representative = np.full(rows * cols, -1, dtype=np.int64)
    collisions = 0
    if len(points):
        order = np.lexsort((rng, slot))
        first = np.ones(len(order), dtype=bool)
        first[1:] = slot[order][1:] != slot[order][:-1]
        rep = order[first]
        representative[slot[rep]] = rep
        ranges[slot[rep]] = rng[rep]
        collisions = int(len(points) - len(rep))
    elev = np.arcsin(np.clip(xyz[:, 2] / np.maximum(rng, 1e-9), -1, 1))
    altitude = np.full(rows, np.nan)
    if len(points):
        order = np.argsort(ring, kind="stable")
        bounds = np.searchsorted(ring[order], np.arange(rows + 1))
        for r in range(rows):  # one median per ring, not per point
            if bounds[r + 1] > bounds[r]:
                altitude[r] = np.median(elev[order[bounds[r] : bounds[r + 1]]])
    known = np.flatnonzero(np.isfinite(altitude))
    if len(known) >= 2:
        altitude = np.interp(np.arange(rows), known, altitude[known])
    else:
        altitude = np.radians(np.linspace(2.0, -24.9, rows))
    return UnfoldedScan(ranges.reshape(rows, cols), slot, representative, altitude, collisions)


class KittiSequence(SequenceBase):
    """A KITTI / SemanticKITTI sequence directory.

    Layout: ``velodyne/NNNNNN.bin``, optional ``labels/NNNNNN.label``, ``poses.txt`` (camera 0
    poses; turned into LiDAR poses with ``calib.txt``'s ``Tr``: ``T_w_velo = inv(Tr) T_w_cam0
    Tr``), ``times.txt``.
    """

    format = "kitti"

    def __init__(self, root: str | Path, rows: int = HDL64_ROWS, cols: int = HDL64_COLS) -> None:
        self.root = Path(root)
        velo = self.root / "velodyne"
        if not velo.is_dir():
            raise DataError(f"{self.root}: no velodyne/ directory (not a KITTI sequence)")
        self.files = sorted(velo.glob("*.bin"))
        if not self.files:
            raise DataError(f"{velo}: no .bin files")
        self.rows, self.cols = rows, cols
        self.name = self.root.name
        self.times = read_times(self.root / "times.txt") if (self.root / "times.txt").is_file() else None
        if self.times is not None and len(self.times) < len(self.files):
            raise DataError(f"{self.root / 'times.txt'}: {len(self.times)} times for {len(self.files)} scans")
        self.poses = None
        if (self.root / "poses.txt").is_file():
            cam = read_kitti_poses(self.root / "poses.txt")
            tr = read_calib_tr(self.root / "calib.txt")
            self.poses = np.linalg.inv(tr) @ cam @ tr
            if len(self.poses) < len(self.files):
                raise DataError(f"{self.root / 'poses.txt'}: {len(self.poses)} poses for {len(self.files)} scans")

    def __getitem__(self, i: int) -> Scan:
        path = self.files[i]
        pts = read_velodyne_bin(path)
        un = unfold_scan(pts, self.rows, self.cols, str(path))
        sensor = SpinningSensor.create(un.altitude, self.cols, sweep_period=SWEEP_PERIOD)
        t0 = float(self.times[i]) if self.times is not None else i * SWEEP_PERIOD
        # the HDL-64E spins clockwise: within a sweep that starts facing forward (azimuth 0),
        # time runs against increasing azimuth
        col_times = t0 + (1.0 - (np.arange(self.cols) + 0.5) / self.cols) * SWEEP_PERIOD
        rep = un.representative.reshape(self.rows, self.cols)
        has = rep >= 0
        intensity = np.zeros((self.rows, self.cols), dtype=np.float32)
        intensity[has] = pts[rep[has], 3]
        gt_point = gt_slot = gt_inst = None
        label_path = self.root / "labels" / (path.stem + ".label")
        if label_path.is_file():
            raw = read_label_file(label_path, len(pts))
            gt_point = L.from_semantic_kitti(raw)
            gt_slot = np.zeros((self.rows, self.cols), dtype=np.uint8)
            gt_slot[has] = gt_point[rep[has]]
            gt_inst = np.zeros((self.rows, self.cols), dtype=np.uint32)
            gt_inst[has] = L.instances_from_semantic_kitti(raw)[rep[has]]
        return Scan(
            ranges=un.ranges,
            sensor=sensor,
            name=path.stem,
            source=str(path),
            intensity=intensity,
            timestamps=col_times,
            cloud=pts[:, :3].copy(),
            point_slot=un.point_slot,
            gt_labels=gt_slot,
            gt_point_labels=gt_point,
            gt_instance=gt_inst,
            gt_pose=None if self.poses is None else self.poses[i],
            meta={"collisions": un.collisions, "frame_time": t0},
        )
