"""The :class:`Organizer`: one sequence's sweeps of points -> ``Scan`` range images, with an exact
map from every input point to its slot.

It takes the rows from a ring field (:mod:`~data_tools.organize.ring_field`), the point order
(:mod:`~data_tools.organize.point_order`) or the beam elevations (:mod:`~data_tools.organize.beams`),
about the spin axis (:mod:`~data_tools.organize.spin_axis`); the columns and slots from the azimuth
(:mod:`~data_tools.organize.columns`); and checks every sweep (:mod:`~data_tools.organize.checks`).
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from data_tools.errors import DataError
from data_tools.organize.beams import estimate_beam_offset, rows_from_beams
from data_tools.organize.checks import OrganizeReport, check_sweep, log
from data_tools.organize.columns import (
    azimuth_direction,
    column_count,
    fill_slots,
    gather,
    row_phases,
    scatter,
    slot_times,
    start_azimuth,
)
from data_tools.organize.point_order import RingMajor, order_layout
from data_tools.organize.polar import TWO_PI, polar, wrap_angles
from data_tools.organize.ring_field import RingField
from data_tools.organize.spin_axis import estimate_spin_axis, find_spin_axis
from prc_slam.scan import Scan, SpinningSensor

METHODS = ("auto", "ring", "order", "beams")


def _nanmedian_rows(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=1)``, NaN for rows without a finite value and no warning about them."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice encountered": a row without returns
        return np.nanmedian(a, axis=1)


_warm = False


def warm_up() -> None:
    """Load (or compile) the organiser's kernels once per process, when the first organiser is
    made: otherwise the first sweep of a run pays for it (0.2-0.6 s), and its organising time is
    charged to PRC (``Scan.meta["organize_seconds"]``)."""
    global _warm
    if _warm:
        return
    _warm = True
    elev = np.radians(np.linspace(-15.0, 15.0, 16))
    az = np.radians(np.arange(0.0, 360.0, 1.0))
    e, a = np.meshgrid(elev, az, indexing="ij")  # ring-major
    r = 10.0 + np.cos(3 * a)
    xyz = np.stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a), r * np.sin(e)], axis=-1)
    ring = np.repeat(np.arange(16), len(az))
    times = np.tile(np.linspace(0.0, 0.1, len(az), endpoint=False), 16)
    points = xyz.reshape(-1, 3)
    n = len(points)
    order = np.random.default_rng(0).permutation(n)
    xyzi = np.ones((n, 4), np.float32)  # a KITTI bin: x, y, z, remission
    xyzi[:, :3] = points
    as_read = {  # with its label file, as the reader gives them (views of the bin's columns)
        "xyz": xyzi[:, :3],
        "intensity": xyzi[:, 3],
        "gt_point_labels": np.zeros(n, np.uint8),
        "gt_point_instance": np.zeros(n, np.uint32),
    }
    for kwargs in (
        {"xyz": points},
        {"xyz": points, "ring": ring, "times": times},
        {"xyz": xyz.transpose(1, 0, 2).reshape(-1, 3)},
        {"xyz": points[order]},
        as_read,
    ):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                org = Organizer(source_name="warm-up", find_spin_axis=False)  # (searched once below)
                for _ in range(2):  # later sweeps of a sequence take other kernels (ring order)
                    org.scan(**kwargs)
        except DataError:
            pass
    estimate_spin_axis(points[:1000])


class Organizer:
    """Organises the sweeps of one sequence into range images (one instance per sequence).

    Parameters
    ----------
    rows, cols : int, optional
        Beams and columns of the sensor when known; otherwise estimated on the first sweep
        (rows: beams found; cols: from the median azimuth step along a ring) and kept.
    altitude : array, optional
        Beam elevations (rad) when known; sets ``rows`` and the beam table.
    method : {"auto", "ring", "order", "beams"}
        ``auto`` uses a ring field when given, else the point order when it is consistent,
        else elevation clustering. The others force one way (``ring`` needs the field).
    source_name : str
        Name of the sequence, for messages.
    sweep_period : float
        Duration of one sweep (s), for per-column times when no per-point times are given.
    spin : {None, "cw", "ccw"}
        The sensor's direction of rotation seen from above (``cw``: azimuth falls in time),
        when the source's convention fixes it (KITTI: ``cw``); otherwise taken from per-point
        times, else from the point order (the order is taken as the firing order).
    start_azimuth : float, optional
        Azimuth (rad) where a sweep starts, when the source's convention fixes it (KITTI: 0);
        otherwise the azimuth of the first point in time (or in order).
    find_spin_axis : bool
        On the first sweep, look for the sensor's spin axis (:func:`estimate_spin_axis`; not with
        a known beam table, whose decoder gives sensor-frame points): points given in a frame
        tilted from it (a vehicle frame) are organised about it, the sensor model's rays turned
        back into the points' frame (``SpinningSensor.mount``), and the tilt said once.

    One instance per sequence and per thread: the beam table, column count, cut azimuth and
    work arrays are kept from sweep to sweep.

    Columns run in firing order from the sweep's start: column ``c`` holds the azimuths
    ``start + direction * (c + phase_r +- 0.5) * 2 pi / cols``; without per-point times, column
    ``c`` is stamped ``frame_time + (c + 0.5) / cols * sweep_period`` only when ``spin`` is given
    (the source fixes its time convention); otherwise the Scan carries no times.
    """

    def __init__(
        self,
        rows: int | None = None,
        cols: int | None = None,
        altitude: np.ndarray | None = None,
        method: str = "auto",
        source_name: str = "seq",
        sweep_period: float = 0.1,
        spin: str | None = None,
        start_azimuth: float | None = None,
        find_spin_axis: bool = True,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"organiser method {method!r}; choose from {METHODS}")
        if spin not in (None, "cw", "ccw"):
            raise ValueError(f"organiser spin {spin!r}; choose from None, 'cw', 'ccw'")
        self.method = method
        self.source_name = source_name
        self.sweep_period = float(sweep_period)
        self.spin = spin
        self.expected_rows = int(rows) if rows is not None else None
        self.cols = int(cols) if cols is not None else None
        self.beam_te: np.ndarray | None = None
        if altitude is not None:
            alt = np.asarray(altitude, dtype=np.float64)
            if alt.ndim != 1 or len(alt) == 0 or not np.isfinite(alt).all():
                raise ValueError("altitude must be a non-empty 1-D array of finite angles (rad)")
            self.beam_te = np.sort(np.tan(alt))[::-1]
            self.expected_rows = len(alt)
        self.ring_field = RingField()
        self.ring_major = RingMajor()
        self.direction: int | None = None if spin is None else (-1 if spin == "cw" else 1)
        self.a0: float | None = None if start_azimuth is None else float(start_azimuth)
        self.phase: np.ndarray | None = None
        self._order_direction: int | None = None
        self._order: tuple[float, float] = (0.0, 0.0)
        self._buffers: dict[str, np.ndarray] = {}
        self.beam_offset: float | None = None
        self._concentration = 1.0
        self._sensor: tuple[tuple, SpinningSensor] | None = None
        self.frames = 0
        self.warnings_total = 0
        #: points' frame -> spin frame (the smallest rotation taking the spin axis to z), None while
        #: the two are the same
        self.rotation: np.ndarray | None = None
        self.spin_tilt_deg = 0.0
        self._find_axis = bool(find_spin_axis) and altitude is None
        warm_up()

    def _work(self, name: str, n: int, dtype) -> np.ndarray:
        """A work array of ``n`` entries kept from sweep to sweep (fresh megabyte arrays cost
        page faults on every sweep, about as much as the organising itself)."""
        buf = self._buffers.get(name)
        if buf is None or len(buf) < n or buf.dtype != dtype:
            buf = np.empty(max(n, int(1.25 * n)), dtype)
            self._buffers[name] = buf
        return buf[:n]

    # ------------------------------------------------------------------ public API
    def scan(
        self,
        xyz: np.ndarray,
        ring: np.ndarray | None = None,
        times: np.ndarray | None = None,
        intensity: np.ndarray | None = None,
        name: str = "000000",
        source: str = "<memory>",
        frame_time: float | None = None,
        gt_point_labels: np.ndarray | None = None,
        gt_point_instance: np.ndarray | None = None,
        gt_pose: np.ndarray | None = None,
    ) -> Scan:
        """Organise one sweep of points (input order) into a Scan with an exact slot map; its
        ``meta["organize_seconds"]`` is the time this took (PRC's cost on unorganised input)."""
        t_start = time.perf_counter()
        xyz = np.asarray(xyz)
        if xyz.ndim != 2 or xyz.shape[1] < 3:
            raise DataError(f"{source}: points must be an (N, 3) array, got shape {xyz.shape}")
        if xyz.dtype.kind not in "fiu":
            raise DataError(f"{source}: points of type {xyz.dtype} are not numeric")
        xyz = xyz[:, :3]
        n = len(xyz)
        for nm, arr in (
            ("ring", ring),
            ("times", times),
            ("intensity", intensity),
            ("gt_point_labels", gt_point_labels),
            ("gt_point_instance", gt_point_instance),
        ):
            if arr is not None and np.shape(arr) != (n,):
                raise DataError(f"{source}: {nm} has shape {np.shape(arr)} for {n} points")
        warnings: list[str] = []
        if ring is not None and self.method == "auto" and n > 1000 and (np.asarray(ring) == ring[0]).all():
            warnings.append(f"{source}: the ring field holds one value ({ring[0]}) for every point; ignored")
            ring = None
        cloud = np.empty((n, 3), np.float32)  # Scan.cloud, filled by polar (no-return rows zeroed)
        if self._find_axis:
            decided, rotation, tilt = find_spin_axis(xyz, source, warnings)
            self._find_axis = not decided
            if rotation is not None:
                self.rotation, self.spin_tilt_deg = rotation, tilt
        if self.beam_offset is None:
            self.beam_offset = 0.0 if ring is not None else estimate_beam_offset(xyz, rotation=self.rotation)
        ok, rng, az, te = (
            self._work("ok", n, np.bool_),
            self._work("rng", n, np.float32),
            self._work("az", n, np.float32),
            self._work("te", n, np.float32),
        )
        if self.rotation is None:
            self._order = polar(xyz, self.beam_offset, ok, rng, az, te, cloud)
        else:  # azimuths and elevations in the spin frame; Scan.cloud keeps the points as given
            spun = np.asarray(xyz, np.float64) @ self.rotation.T
            self._order = polar(spun, self.beam_offset, ok, rng, az, te, cloud)
            cloud[ok] = xyz[ok]
        n_ok = int(ok.sum())
        if n_ok == 0:
            what = f"no point with a return ({n} points, all NaN/inf, at the origin or beyond 100 km)"
            if self._sensor is None:  # the first sweep: no geometry to give it
                raise DataError(f"{source}: {what}")
            return self._empty(cloud, name, source, frame_time, gt_point_labels, gt_point_instance, gt_pose, what)
        if times is not None:
            times = np.asarray(times, dtype=np.float64)
            if not np.isfinite(times[ok]).all():
                raise DataError(f"{source}: non-finite per-point times")
        if n_ok < n:
            warnings.append(
                f"{source}: {n - n_ok} of {n} points have no return (NaN/inf, at the origin or beyond 100 km); label 0"
            )

        method, row, rows = self._rows(ok, rng, az, te, ring, source, warnings)
        if self.direction is None:
            order = self._order_direction if method in ("ring-major", "column-major") else None
            self.direction = azimuth_direction(az, ok, row, times, order)
        if self.a0 is None:
            self.a0 = start_azimuth(az, ok, times)
        s, a0 = self.direction, self.a0
        if self.cols is None:
            self.cols = column_count(az, ok, row, rows, source)
        cols = self.cols
        inv_step = cols / TWO_PI
        if self.phase is None or len(self.phase) != rows:
            self.phase = row_phases(az, row, rows, a0, s, inv_step)
        rep = self._work("rep", rows * cols, np.int64)
        slot, rep, per_row, collisions, multi = scatter(az, rng, row, a0, s, inv_step, self.phase, rows, cols, rep)
        report = self._check(method, rows, cols, per_row, collisions, n_ok, n - n_ok, source, warnings, multi)
        sensor = self._sensor_model(rows, cols, s, a0)
        inten = None
        if intensity is not None:
            src = np.asarray(intensity)
            if src.dtype.kind not in "fiub":
                raise DataError(f"{source}: intensity of type {src.dtype} is not numeric")
            inten = gather(rep, src, np.empty(rows * cols, np.float32)).reshape(rows, cols)
        t = None if times is None else slot_times(times, rep, rows, cols)
        scan = self._finish(
            cloud, rng, slot, rep, rows, cols, sensor, t, inten, name, source, frame_time,
            gt_point_labels, gt_point_instance, gt_pose, report, collisions, slot_times_given=times is not None,
        )  # fmt: skip
        t_end = time.perf_counter()
        scan.meta["organize_seconds"] = t_end - t_start
        scan.meta["organize_span"] = (t_start, t_end)  # perf_counter interval (overlap credit, pipeline.NextFrame)
        return scan

    def scan_organized(
        self,
        grid_xyz: np.ndarray,
        times: np.ndarray | None = None,
        intensity: np.ndarray | None = None,
        name: str = "000000",
        source: str = "<memory>",
        frame_time: float | None = None,
    ) -> Scan:
        """A sweep already organised as ``(H, W, 3)`` (rows = beams, e.g. the Ouster ROS driver).

        Zeros or NaN are no returns. Rows are put top beam first (by their median elevation);
        the slot map is the identity up to that row order; the sensor model (beam elevations,
        azimuth direction, per-row azimuth offsets) is estimated from the grid.
        """
        g = np.asarray(grid_xyz)
        if g.ndim != 3 or g.shape[2] < 3 or g.shape[0] < 1 or g.shape[1] < 2:
            raise DataError(f"{source}: an organised cloud must be (H, W, 3), got shape {g.shape}")
        H, W = g.shape[:2]
        src = g[..., :3].reshape(-1, 3)
        n_all = len(src)
        ok, rng, az, te = (np.empty(n_all, bool), np.empty(n_all, np.float32), np.empty(n_all), np.empty(n_all))
        flat = np.empty((n_all, 3), np.float32)
        polar(src, 0.0, ok, rng, az, te, flat)
        if not ok.any():
            raise DataError(f"{source}: no point with a return in the {H} x {W} organised cloud")
        warnings: list[str] = []
        okg = ok.reshape(H, W)
        teg = np.where(okg, te.reshape(H, W), np.nan)
        with np.errstate(all="ignore"):
            med = np.array([np.nanmedian(r) if np.isfinite(r).any() else np.nan for r in teg])
        known = np.isfinite(med)
        empty_rows = int((~known).sum())
        if known.sum() >= 2:
            med = np.interp(np.arange(H), np.flatnonzero(known), med[known])
        else:
            med = np.where(known, med, med[known][0] if known.any() else 0.0)
        # rows without a return between rows with returns (every other beam off: a sensor in a
        # reduced-beam mode, a dead laser) go after the others, so that neighbouring beams are
        # neighbouring rows (interleaved, they left PRC no row neighbours: every return noise)
        have = np.flatnonzero(known)
        inner = ~known & (np.arange(H) > have[0]) & (np.arange(H) < have[-1]) if len(have) else np.zeros(H, bool)
        order = np.lexsort((-med, inner))  # top beam first (stable), the inner empty rows last
        inv = np.empty(H, np.int64)
        inv[order] = np.arange(H)
        if inner.any():
            warnings.append(
                f"{source}: {int(inner.sum())} of {H} rows of the organised cloud hold no return between rows that do "
                "(a reduced-beam mode?): put after the others, so that neighbouring beams are neighbouring rows"
            )
        ranked = order[~inner[order]]
        if not np.all(np.diff(ranked) > 0) and not np.all(np.diff(ranked) < 0):
            msg = f"{source}: rows of the organised cloud are not ordered by elevation; reordered top beam first"
            warnings.append(msg)
        row = np.repeat(inv, W)
        row[~ok] = -1
        # azimuth direction along the columns
        dg = np.where(okg[:, 1:] & okg[:, :-1], wrap_angles(np.diff(az.reshape(H, W), axis=1)), np.nan)
        s = 1 if np.nansum(np.sign(dg)) >= 0 else -1
        col = np.tile(np.arange(W), H)
        c_az = s * TWO_PI * (col + 0.5) / W
        a0 = float(np.angle(np.exp(1j * (az[ok] - c_az[ok])).mean()))
        offs = np.zeros(H)
        resid = np.where(ok, wrap_angles(az - c_az - a0), np.nan).reshape(H, W)
        offs[inv] = np.nan_to_num(_nanmedian_rows(resid))
        slot = np.repeat(inv, W) * W + col  # no-return points keep their own (empty) slot
        rep = np.full(H * W, -1, np.int64)
        rep[slot[ok]] = np.flatnonzero(ok)
        per_row = np.bincount(row[ok], minlength=H)
        self.expected_rows = self.expected_rows or H
        report = self._check("organized", H, W, per_row, 0, int(ok.sum()), int((~ok).sum()), source, warnings)
        report.empty_rows = max(report.empty_rows, empty_rows)
        sensor = SpinningSensor.create(
            np.arctan(med[order]), W, beam_azimuth=offs, azimuth0=a0, direction=s, sweep_period=self.sweep_period
        )
        t = None
        if times is not None:
            t = np.asarray(times, dtype=np.float64)
            if t.shape == (H, W):
                t = t[order]
            elif t.shape != (W,):
                raise DataError(f"{source}: times of shape {t.shape} for a {H} x {W} cloud")
        inten = None
        if intensity is not None:
            inten = np.asarray(intensity, dtype=np.float32)
            if inten.shape != (H, W):
                raise DataError(f"{source}: intensity of shape {inten.shape} for a {H} x {W} cloud")
            inten = inten[order]
        return self._finish(
            flat, rng, slot, rep, H, W, sensor, t, inten, name, source, frame_time, None, None, None, report, 0,
            slot_times_given=t is not None,
        )  # fmt: skip

    # ------------------------------------------------------------------ rows
    def _rows(self, ok, rng, az, te, ring, source, warnings) -> tuple[str, np.ndarray, int]:
        """The way the rows were found, the row of every point (-1: no return) and the row count."""
        method = self.method
        if ring is not None and method in ("auto", "ring"):
            row, self.beam_te = self.ring_field.rows(np.asarray(ring), ok, te, self.beam_te, source, warnings)
            if self.expected_rows is None:
                self.expected_rows = len(self.ring_field.ids)
            return "ring-field", row, len(self.ring_field.ids)
        if method == "ring":
            raise DataError(f"{source}: organiser method 'ring' but the source has no ring field")
        layout = "unordered"
        if method in ("auto", "order"):
            layout, self._order_direction = order_layout(*self._order, method, source)
        if layout == "ring-major":
            row, self.beam_te = self.ring_major.rows(
                ok, az, te, self._order_direction, self.cols, self.beam_te, self._work, source, warnings
            )
            return "ring-major", row, len(self.beam_te)
        row, self.beam_te, self._concentration = rows_from_beams(
            ok, rng, te, self.beam_te, self._concentration, self.expected_rows, self._work("row", len(te), np.int64),
            source, warnings,
        )  # fmt: skip
        return ("column-major" if layout == "column-major" else "beams"), row, len(self.beam_te)

    # ------------------------------------------------------------------ checks and the Scan
    def _check(self, method, rows, cols, per_row, collisions, n_ok, n_bad, source, warnings, multi=0) -> OrganizeReport:
        report = check_sweep(
            method, rows, cols, per_row, collisions, n_ok, n_bad, self.expected_rows, source, warnings, multi
        )
        self.warnings_total += len(warnings)
        self.frames += 1
        return report

    def _empty(self, cloud, name, source, frame_time, gt_point_labels, gt_point_instance, gt_pose, what) -> Scan:
        """A sweep without a single return after sweeps that had some (an empty message, a blocked
        sensor): the sequence's range image with every slot empty, each input point (if any) in an
        empty slot with label 0, said once per sweep, so that the frame keeps its place in every
        output (label files, rewritten recordings) instead of being skipped."""
        sensor = self._sensor[1]
        rows, cols = sensor.rows, sensor.cols
        n = len(cloud)
        warnings = [f"{source}: {what}: an empty sweep, every point labelled no return"] if n else []
        for w in warnings:  # (a sweep of no points at all is said by the pipeline)
            log.warning(w)
        self.warnings_total += len(warnings)
        self.frames += 1
        report = OrganizeReport("empty", 0, self.expected_rows, cols, 0.0, rows, n, warnings)
        none, empty = np.zeros(n, np.int64), np.full(rows * cols, -1, np.int64)  # every point in slot 0, empty
        return self._finish(
            cloud, np.zeros(n, np.float32), none, empty, rows, cols, sensor, None, None, name,
            source, frame_time, gt_point_labels, gt_point_instance, gt_pose, report, 0, slot_times_given=False,
        )  # fmt: skip

    def _sensor_model(self, rows: int, cols: int, s: int, a0: float) -> SpinningSensor:
        """The sequence's sensor model, one object for as long as its parameters hold (its
        slot directions are then computed once per sequence, not once per sweep)."""
        altitude = np.arctan(self.beam_te) if self.beam_te is not None and len(self.beam_te) == rows else np.zeros(rows)
        beam_azimuth = s * (TWO_PI / cols) * (self.phase - 0.5)
        key = (rows, cols, s, a0, self.sweep_period, altitude.tobytes(), beam_azimuth.tobytes())
        if self._sensor is None or self._sensor[0] != key:
            sensor = SpinningSensor.create(
                altitude, cols, beam_azimuth=beam_azimuth, azimuth0=a0, direction=s, sweep_period=self.sweep_period,
                mount=None if self.rotation is None else self.rotation.T,
            )  # fmt: skip
            self._sensor = (key, sensor)
        return self._sensor[1]

    def _finish(
        self, cloud, rng, slot, rep, rows, cols, sensor, t, inten, name, source, frame_time,
        gt_point_labels, gt_point_instance, gt_pose, report, collisions, slot_times_given,
    ) -> Scan:  # fmt: skip
        """The Scan of a sweep from its slot map: the representatives' ranges and points, the
        ground truth per slot, the no-return points in an empty slot and the frame time."""
        size = rows * cols
        ranges, slot_xyz = fill_slots(rep, rng, cloud)
        point_slot = slot
        if report.nonfinite_points:
            lost = slot < 0
            if lost.any():
                empty = np.flatnonzero(rep < 0)
                if len(empty) == 0:
                    raise DataError(
                        f"{source}: {int(lost.sum())} no-return points but the range image has no empty slot "
                        "to hold them"
                    )
                point_slot = slot.copy()
                point_slot[lost] = empty[0]
        if frame_time is None:
            frame_time = float(np.min(t)) if t is not None else self.frames * self.sweep_period
        if t is None and not slot_times_given and self.spin is not None:
            # the source fixes its time convention: column c fired at (c + 0.5) / cols of the
            # sweep (columns follow time). Without it no times are made up (no deskewing).
            t = frame_time + (np.arange(cols) + 0.5) / cols * self.sweep_period
        gt_slot = gt_inst = None
        if gt_point_labels is not None:
            src = np.ascontiguousarray(gt_point_labels, dtype=np.uint8)
            gt_slot = gather(rep, src, np.empty(size, np.uint8)).reshape(rows, cols)
        if gt_point_instance is not None:
            src = np.ascontiguousarray(gt_point_instance, dtype=np.uint32)
            gt_inst = gather(rep, src, np.empty(size, np.uint32)).reshape(rows, cols)
        return Scan(
            ranges=ranges.reshape(rows, cols),
            sensor=sensor,
            name=name,
            source=source,
            intensity=inten,
            timestamps=t,
            xyz=slot_xyz.reshape(rows, cols, 3),
            cloud=cloud,
            point_slot=point_slot,
            gt_labels=gt_slot,
            gt_point_labels=None if gt_point_labels is None else np.asarray(gt_point_labels),
            gt_instance=gt_inst,
            gt_pose=gt_pose,
            meta={"organize": report.as_dict(), "collisions": int(collisions), "frame_time": float(frame_time)},
        )
