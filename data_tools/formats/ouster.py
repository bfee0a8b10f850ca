"""Ouster sweeps decoded to organised ``*.npz`` arrays (see ``../shared/data/README.md``).

Each file holds one sweep in measurement order: ``range_mm`` (beams x measurement ids,
0 = no return), ``reflectivity``, ``column_ts_ns``, ``column_valid``, ``beam_altitude_deg``,
``beam_azimuth_deg``, ``pixel_shift_by_row`` and optionally ``xyz_lidar_m``.
"""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path

import numpy as np

from data_tools.errors import DataError
from data_tools.sequence import Reader, SequenceBase
from prc_slam.scan import Scan, SpinningSensor

log = logging.getLogger("prc_slam.readers")

REQUIRED = ("range_mm", "column_ts_ns", "beam_altitude_deg", "beam_azimuth_deg", "pixel_shift_by_row")


def destagger(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Shift each row ``r`` of a measurement-order image right by ``shift[r]`` columns
    (Ouster's destaggering), so that a column holds one azimuth for all beams."""
    cols = image.shape[1]
    idx = (np.arange(cols)[None, :] - np.asarray(shift)[:, None]) % cols
    return np.take_along_axis(image, idx.reshape(idx.shape + (1,) * (image.ndim - 2)), axis=1)


def read_ouster_npz(path: str | Path, *, destaggered: bool = True, name: str | None = None) -> Scan:
    """Read one decoded Ouster sweep as a Scan (rows = beams, columns = measurement ids).

    Parameters
    ----------
    path : path of the ``.npz``
    destaggered : bool
        Shift rows by ``pixel_shift_by_row`` so that a column holds one azimuth for all beams
        (the default: PRC's tests across scan lines compare a slot with the slots above and
        below it, which in measurement order lie up to 22 deg away on an OS0); False keeps the
        measurement (emission) order of the raw stream.
    """
    path = Path(path)
    try:
        with np.load(path) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise DataError(f"{path}: cannot read Ouster npz: {exc}") from exc
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise DataError(f"{path}: missing arrays {missing}")
    return ouster_scan(
        range_mm=data["range_mm"],
        column_ts_ns=data["column_ts_ns"],
        beam_altitude_deg=data["beam_altitude_deg"],
        beam_azimuth_deg=data["beam_azimuth_deg"],
        pixel_shift_by_row=data["pixel_shift_by_row"],
        column_valid=data.get("column_valid"),
        reflectivity=data.get("reflectivity"),
        xyz_lidar_m=data.get("xyz_lidar_m"),
        destaggered=destaggered,
        name=name or path.stem,
        source=str(path),
    )


def ouster_scan(
    *,
    range_mm: np.ndarray,
    column_ts_ns: np.ndarray,
    beam_altitude_deg: np.ndarray,
    beam_azimuth_deg: np.ndarray,
    pixel_shift_by_row: np.ndarray,
    column_valid: np.ndarray | None = None,
    reflectivity: np.ndarray | None = None,
    xyz_lidar_m: np.ndarray | None = None,
    destaggered: bool = True,
    name: str = "000000",
    source: str = "<memory>",
    meta: dict | None = None,
) -> Scan:
    """One Ouster sweep in measurement order (the arrays of a decoded ``.npz`` or of an SDK
    ``LidarFrame``) as a Scan: rows = beams, columns = measurement ids, checked for shape,
    finiteness and monotonic column times. Shared by the ``.npz`` and the pcap readers, so both
    build exactly the same Scan from the same sweep.

    Parameters
    ----------
    range_mm : (H, W) range in millimetres, 0 = no return
    column_ts_ns : (W,) column timestamps (ns)
    beam_altitude_deg, beam_azimuth_deg, pixel_shift_by_row : (H,) beam intrinsics
    column_valid : (W,) bool, optional; columns not received hold no return
    reflectivity : (H, W), optional
    xyz_lidar_m : (H, W, 3), optional Cartesian coordinates in the lidar frame (kept as ``Scan.xyz``)
    destaggered : shift rows by ``pixel_shift_by_row`` so that columns are azimuths
    meta : extra entries for ``Scan.meta``
    """
    rng = np.asarray(range_mm)
    if rng.ndim != 2:
        raise DataError(f"{source}: range_mm must be 2-D, got shape {rng.shape}")
    rows, cols = rng.shape
    if rng.dtype.kind == "f":  # millimetres are whole numbers (the sensor's uint32 field)
        fin = rng[np.isfinite(rng) & (rng > 0)]
        if fin.size and (fin != np.round(fin)).mean() > 0.5:
            raise DataError(
                f"{source}: range_mm holds fractional values (median {float(np.median(fin)):.4g}): metres? "
                "it must hold whole millimetres (uint32, 0 = no return)"
            )
    arrays = {
        "beam_altitude_deg": np.asarray(beam_altitude_deg),
        "beam_azimuth_deg": np.asarray(beam_azimuth_deg),
        "pixel_shift_by_row": np.asarray(pixel_shift_by_row),
        "column_ts_ns": np.asarray(column_ts_ns),
    }
    for key, shape in (
        ("beam_altitude_deg", (rows,)),
        ("beam_azimuth_deg", (rows,)),
        ("pixel_shift_by_row", (rows,)),
        ("column_ts_ns", (cols,)),
    ):
        if arrays[key].shape != shape:
            raise DataError(f"{source}: {key} has shape {arrays[key].shape}, expected {shape}")
    ranges = rng.astype(np.float64) / 1000.0
    if not np.isfinite(ranges).all():
        raise DataError(f"{source}: non-finite ranges")
    valid_cols = np.ones(cols, bool) if column_valid is None else np.asarray(column_valid).astype(bool)
    if valid_cols.shape != (cols,):
        raise DataError(f"{source}: column_valid has shape {valid_cols.shape}, expected {(cols,)}")
    ranges[:, ~valid_cols] = 0.0
    ts = arrays["column_ts_ns"].astype(np.float64) * 1e-9
    if (np.diff(ts[valid_cols]) < 0).any():
        raise DataError(f"{source}: column timestamps are not monotonic")
    shift = arrays["pixel_shift_by_row"].astype(np.int64)
    intensity = (np.zeros((rows, cols)) if reflectivity is None else np.asarray(reflectivity)).astype(np.float32)
    xyz = xyz_lidar_m
    if xyz is not None and xyz.shape != (rows, cols, 3):
        raise DataError(f"{source}: xyz_lidar_m has shape {xyz.shape}, expected {(rows, cols, 3)}")
    timestamps = np.broadcast_to(ts[None, :], (rows, cols)).copy()
    if destaggered:
        ranges = destagger(ranges, shift)
        intensity = destagger(intensity, shift)
        timestamps = destagger(timestamps, shift)
        xyz = None if xyz is None else destagger(xyz, shift)
    # Ouster: encoder angle 2*pi*(1 - m/W) for measurement id m, beam azimuth offset subtracted.
    sensor = SpinningSensor.create(
        np.radians(arrays["beam_altitude_deg"]),
        cols,
        beam_azimuth=-np.radians(arrays["beam_azimuth_deg"]),
        column_shift=-shift.astype(float) if destaggered else None,
        azimuth0=2.0 * np.pi + np.pi / cols,
        direction=-1,
        sweep_period=float(ts[valid_cols][-1] - ts[valid_cols][0]) * cols / max(int(valid_cols.sum()) - 1, 1)
        if valid_cols.sum() > 1
        else 0.1,
    )
    return Scan(
        ranges=ranges.astype(np.float32),
        sensor=sensor,
        name=name,
        source=source,
        intensity=intensity,
        timestamps=timestamps,
        xyz=None if xyz is None else xyz.astype(np.float32),
        meta={"destaggered": destaggered, "invalid_columns": int((~valid_cols).sum()), **(meta or {})},
    )


class OusterSequence(SequenceBase):
    """One or more decoded Ouster sweeps (a ``.npz`` file or a directory of them, sorted)."""

    format = "ouster"

    def __init__(self, path: str | Path, *, destaggered: bool = True) -> None:
        path = Path(path)
        self.files = sorted(path.glob("*.npz")) if path.is_dir() else [path]
        if not self.files:
            raise DataError(f"{path}: no .npz files")
        self.root = path
        self.name = path.stem
        self.destaggered = destaggered
        self.poses = None
        self.times = None
        self._beams: tuple[int, np.ndarray] | None = None  # the first sweep read's beam altitudes
        self._mixed_warned = False

    def __getitem__(self, i: int) -> Scan:
        scan = read_ouster_npz(self.files[i], destaggered=self.destaggered, name=f"{i:06d}")
        if len(self.files) > 1 and not self._mixed_warned:
            self._check_same_sensor(i, np.degrees(scan.sensor.altitude))
        return scan

    def _check_same_sensor(self, i: int, alt: np.ndarray) -> None:
        """Warn once when a sweep's beam table (``alt``, degrees) is not the first sweep's: the
        folder mixes sensors (before, the decoded folder of three Ouster models ran as one sequence,
        and odometry stopped at frame 1 on a frame time going back, without a word about the cause)."""
        if self._beams is None:
            self._beams = (i, alt)
            return
        j, ref = self._beams
        if alt.shape == ref.shape and np.allclose(alt, ref, atol=0.01):
            return
        self._mixed_warned = True

        def table(a: np.ndarray) -> str:
            return f"{len(a)} beams, {a.min():.2f}..{a.max():.2f} deg"

        log.warning(
            "%s: its beam table (%s) is not that of %s (%s): the folder mixes sensors, and odometry across them "
            "is meaningless",
            self.files[i],
            table(alt),
            self.files[j].name,
            table(ref),
        )


def detect(path: Path) -> bool:
    """Decoded Ouster sweeps: an ``.npz`` file, or a directory holding some."""
    return any(path.glob("*.npz")) if path.is_dir() else path.suffix == ".npz"


READER = Reader(
    "ouster",
    ("destaggered",),
    detect,
    lambda path, options: OusterSequence(path, destaggered=bool(options.get("destaggered", True))),
)
