"""KITTI odometry / SemanticKITTI directories: bins, labels, poses, calib, times.

The Velodyne bins of KITTI hold the points of one sweep ring by ring (one laser after
another, azimuth increasing within a ring), no-return points dropped; bins written from other
sensors may be ordered otherwise. Every sweep is organised into a range image by
:class:`data_tools.organize.Organizer` (point order detected, beams and columns estimated, no
sensor constants assumed); every input point keeps its slot, so labels computed on the image
map back to every input point in input order.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from data_tools.errors import DataError
from data_tools.formats.trajectory_io import read_kitti_poses, read_times, warn_time_gaps
from data_tools.organize import Organizer
from data_tools.sequence import ORGANISER_OPTIONS, Reader, SequenceBase, organiser_hints
from data_tools.units import warn_unless_metres
from prc_slam import labels as L
from prc_slam.scan import Scan

SWEEP_PERIOD = 0.1

log = logging.getLogger("prc_slam.readers")


def read_velodyne_bin(path: str | Path, allow_nonfinite: bool = False) -> np.ndarray:
    """Read a KITTI ``.bin`` as ``float32[N, 4]`` (x, y, z, remission).

    Points with NaN/inf values raise :class:`DataError` unless ``allow_nonfinite`` (then they
    are no-return points: the organiser counts them and gives them label 0)."""
    path = Path(path)
    try:
        raw = np.fromfile(path, dtype=np.float32)
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    if raw.size % 4:
        raise DataError(f"{path}: truncated: {path.stat().st_size} bytes is not a whole number of 16-byte points")
    pts = raw.reshape(-1, 4)
    if allow_nonfinite or np.isfinite(raw).all():  # the flat check first: the per-point one is 10x slower
        return pts
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
    width = None
    if n_points and size != 4 * n_points:
        width = {2 * n_points: "uint16", n_points: "uint8", 8 * n_points: "uint64"}.get(size)
    hint = f" (one {width} per point? SemanticKITTI labels are uint32)" if width else ""
    if size % 4:
        raise DataError(f"{path}: truncated: {size} bytes is not a whole number of uint32 labels{hint}")
    lab = np.fromfile(path, dtype=np.uint32)
    if n_points is not None and lab.size != n_points:
        raise DataError(f"{path}: {lab.size} labels for {n_points} points{hint}")
    return lab


#: SemanticKITTI's semantic ids (lower 16 bits of a label); any other id is read as unclassified
_KNOWN_SEMANTIC = np.zeros(1 << 16, dtype=bool)
_KNOWN_SEMANTIC[list(L.SEMANTIC_KITTI_TO_CODE)] = True
#: a label file with more than this share of other ids is not SemanticKITTI's (warned)
UNKNOWN_SEMANTIC_SHARE = 0.05


#: a median step between frame times above this (s) is taken for times in other units (warned)
MAX_FRAME_STEP = 10.0


def warn_unless_seconds(times: np.ndarray, source: str | Path) -> bool:
    """Warn when the frame times are more than :data:`MAX_FRAME_STEP` apart (median step): a
    ``times.txt`` in milliseconds or nanoseconds (ROS stamps) is read as seconds, which makes the
    odometry guard's speed bound meaningless and the TUM trajectories' times wrong. Returns
    whether it warned."""
    step = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    if step <= MAX_FRAME_STEP:
        return False
    log.warning(
        "%s: the frames are %.4g s apart (median step): times not in seconds? A 10 Hz sensor's frames are 0.1 s "
        "apart (100 in milliseconds, 1e8 in nanoseconds); the times are read as seconds (the odometry's speed "
        "bound, the TUM trajectories)",
        source,
        step,
    )
    return True


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


class KittiSequence(SequenceBase):
    """A KITTI / SemanticKITTI sequence directory, organised by :class:`~data_tools.organize.Organizer`.

    Layout: ``velodyne/NNNNNN.bin``, optional ``labels/NNNNNN.label``, ``poses.txt`` (camera 0
    poses; turned into LiDAR poses with ``calib.txt``'s ``Tr``: ``T_w_velo = inv(Tr) T_w_cam0
    Tr``), ``times.txt``.

    The bins may come from any spinning sensor: the organiser detects the point order
    (ring-major as the HDL-64E's KITTI bins, column-major, either azimuth direction, or none)
    and estimates beams and columns on the first frame unless ``rows``/``cols``/``altitude``
    are given.

    The KITTI odometry bins are motion-compensated already, so by default the scans carry no
    per-point times (as KISS-ICP's KITTI loader: no deskewing; with made-up column times KISS-ICP's
    frame-to-frame error on KITTI 00 grew from 0.086 to 0.358 m). For uncompensated sweeps in this
    layout give ``clockwise``: times then follow the KITTI convention (the sweep starts and ends at
    azimuth 0, ``SWEEP_PERIOD`` long, turning clockwise, or counter-clockwise with ``False``).
    """

    format = "kitti"

    def __init__(
        self,
        root: str | Path,
        rows: int | None = None,
        cols: int | None = None,
        *,
        altitude: np.ndarray | None = None,
        method: str = "auto",
        clockwise: bool | None = None,
        sweep_period: float = SWEEP_PERIOD,
    ) -> None:
        self.root = Path(root)
        velo = self.root / "velodyne"
        if not velo.is_dir():
            raise DataError(f"{self.root}: no velodyne/ directory (not a KITTI sequence)")
        self.files = sorted(velo.glob("*.bin"))
        if not self.files:
            raise DataError(f"{velo}: no .bin files")
        self.name = self.root.name
        self.clockwise = clockwise
        self._units_checked = False  # the first sweep read is checked for metres
        self.sweep_period = float(sweep_period)
        self.organizer = Organizer(
            rows=rows, cols=cols, altitude=altitude, method=method, source_name=str(self.root),
            sweep_period=self.sweep_period, spin=None if clockwise is None else ("cw" if clockwise else "ccw"),
            start_azimuth=None if clockwise is None else 0.0,
        )  # fmt: skip
        self.times = read_times(self.root / "times.txt") if (self.root / "times.txt").is_file() else None
        if self.times is not None:
            self.times = self._per_file(self.times, self.root / "times.txt", "times")
            warn_time_gaps(self.times, self.root / "times.txt")
            warn_unless_seconds(self.times, self.root / "times.txt")
        self.poses = None
        if (self.root / "poses.txt").is_file():
            cam = read_kitti_poses(self.root / "poses.txt")
            tr = read_calib_tr(self.root / "calib.txt")
            self.poses = self._per_file(np.linalg.inv(tr) @ cam @ tr, self.root / "poses.txt", "poses")

    def _per_file(self, rows: np.ndarray, path: Path, what: str) -> np.ndarray:
        """The rows of ``times.txt`` / ``poses.txt`` (one per line) of the sweeps present, in file order.

        KITTI numbers its sweeps from 0 and gives one line per sweep. A folder holding only some of
        them (``000010.bin``..``000015.bin``, or numbers with gaps) beside the full files takes line
        ``k + 1`` for ``k.bin`` (before, the first lines were given to whatever sweeps there were: a
        silently wrong ground truth). Files with other names take the lines in order, warned when
        there are more lines than files (which lines belong to them cannot be told)."""
        n = len(self.files)
        if len(rows) < n:
            raise DataError(f"{path}: {len(rows)} {what} for {n} scans")
        stems = [f.stem for f in self.files]
        numbers = np.array([int(s) for s in stems]) if all(s.isdigit() for s in stems) else None
        if numbers is None and len(rows) > n:
            log.warning(
                "%s: %d %s for %d scans whose names are not frame numbers (e.g. %s.bin): the first %d lines are "
                "taken; name the scans by their line (000000.bin, ...) or give one line per scan",
                path, len(rows), what, n, stems[0], n,
            )  # fmt: skip
        if numbers is None or np.array_equal(numbers, np.arange(n)):
            return rows[:n]
        if len(rows) == n:  # one line per sweep present: in order
            return rows
        if numbers.max() >= len(rows):
            raise DataError(
                f"{path}: {len(rows)} {what} for scans numbered {stems[0]}..{stems[-1]} ({n} scans): "
                f"give one line per scan present, or the sequence's full file"
            )
        first = f"{stems[0]}.bin: line {numbers[0] + 1}"
        log.info("%s: %s of the %d scans taken by their numbers (%s)", path, what, n, first)
        return rows[numbers]

    def point_times(self, pts: np.ndarray, t0: float) -> np.ndarray:
        """Per-point times of a sweep starting at ``t0`` under the KITTI convention (azimuth 0
        at the start and the end, turning clockwise; ``clockwise=False``: counter-clockwise).
        The Scan carries the same times per column."""
        az = np.nan_to_num(np.arctan2(pts[:, 1], pts[:, 0]).astype(np.float64))
        frac = (az / (2.0 * np.pi)) % 1.0
        if self.clockwise is not False:
            frac = (1.0 - frac) % 1.0
        return t0 + frac * self.sweep_period

    def _reference(self, path: Path, n_points: int) -> np.ndarray | None:
        """The sweep's SemanticKITTI labels, or None (warned) when the file does not fit the sweep:
        the frame is then classified and registered, only not scored (a wrong label file used to
        skip the whole frame). A file mostly of ids SemanticKITTI does not define is warned too
        (they are scored as unclassified)."""
        try:
            raw = read_label_file(path, n_points)
        except DataError as exc:
            log.warning("%s: this frame is not scored", exc)
            return None
        unknown = ~_KNOWN_SEMANTIC[raw & 0xFFFF]
        share = float(unknown.mean()) if len(raw) else 0.0
        if share > UNKNOWN_SEMANTIC_SHARE:
            example = int(raw[np.argmax(unknown)] & 0xFFFF)
            log.warning(
                "%s: %.0f%% of the labels have a semantic id SemanticKITTI does not define (e.g. %d): "
                "not SemanticKITTI labels? They are scored as unclassified",
                path,
                100 * share,
                example,
            )
        return raw

    def __getitem__(self, i: int) -> Scan:
        path = self.files[i]
        pts = read_velodyne_bin(path, allow_nonfinite=True)
        if not self._units_checked:
            self._units_checked = True
            warn_unless_metres(pts[:, :3], path, "bins")
        t0 = float(self.times[i]) if self.times is not None else i * self.sweep_period
        gt_point = gt_inst = None
        label_path = self.root / "labels" / (path.stem + ".label")
        if label_path.is_file():
            raw = self._reference(label_path, len(pts))
            if raw is not None:
                gt_point = L.from_semantic_kitti(raw)
                gt_inst = L.instances_from_semantic_kitti(raw)
        return self.organizer.scan(
            pts[:, :3],
            intensity=pts[:, 3],
            name=path.stem,
            source=str(path),
            frame_time=t0,
            gt_point_labels=gt_point,
            gt_point_instance=gt_inst,
            gt_pose=None if self.poses is None else self.poses[i],
        )


def detect(path: Path) -> bool:
    """A KITTI sequence: a directory with ``velodyne/``."""
    return path.is_dir() and (path / "velodyne").is_dir()


def _open(path: Path, options: dict[str, object]) -> KittiSequence:
    return KittiSequence(path, **organiser_hints(options))


READER = Reader("kitti", ORGANISER_OPTIONS, detect, _open)
