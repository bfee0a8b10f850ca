"""``OnlineDetector``: the per-scan-line detectors run together on a stream of scans.

Labels per slot, combined as Sec. 8 says: the coarse classes (68 horizontal, 69 vertical,
5 vegetation), overwritten by ground (2), curb (66) and vehicle (65); car points behind a
verified curb keep their coarse class.

Spinning multi-beam sensors take the path of :mod:`prc_slam.online.spinning` for cars (and, beside
Sec. 6, for curb faces; the column ground where columns are too short for Sec. 5 (a));
``OnlineDetector.paper()`` keeps the paper's per-column car algorithm on every sensor.

With more than one numba thread the coarse classifier splits its lines between threads and the
curb detectors run beside the spinning car path (:mod:`prc_slam.util.threads`); the results are
the same with any thread count (``NUMBA_NUM_THREADS=1``: everything in the calling thread).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from prc_slam import labels as L
from prc_slam.online.car import CarParams, detect_cars
from prc_slam.online.coarse import CoarseParams, CoarseResult, coarse_classify
from prc_slam.online.curb import CurbParams, CurbResult, detect_curbs
from prc_slam.online.ground import GroundDetector, GroundParams
from prc_slam.online.noise import (
    HALFWAY_DEG,
    beam_gaps,
    coarse_vegetation_spacing,
    column_runs,
    labelled_over_spacing,
    noise_baseline,
    range_noise,
    ring_smooth_at,
)
from prc_slam.online.spinning import (
    SpinningCarParams,
    SpinningCars,
    column_ground,
    detect_cars_spinning,
    detect_curbs_spinning,
    local_ground,
)
from prc_slam.prc.ground import GroundModelError, beam_order, ground_plane, levelling_rotation
from prc_slam.scan import ProfilerSensor, Scan, SpinningSensor
from prc_slam.util.threads import side_by_side

#: a stream of spinning sweeps whose first ground plane tilts more than this (deg) is levelled for
#: the detectors, every sweep (:meth:`OnlineDetector.level_sweep`): they measure heights along the
#: sensor's z, so a tilt of a few degrees (a tilted mount, a vehicle frame, a hillside) put the far
#: road metres off its height. KITTI 00 frames 0-2 pitched by 2 / 3 / 15 deg (2.4 / 3.3 / 14.8 deg
#: from their ground): ground F1 0.72 -> 0.02 / 0.06 / 0.03, vehicles 0.82 -> 0.02 / 0.08 / 0.02;
#: levelled 0.86 / 0.78-0.79. KITTI's own sweeps tilt 1.6-2.0 deg from their ground and stay as
#: they are: levelled, their ground F1 rises 0.72 -> 0.85 but vehicle precision falls 0.87 -> 0.77
#: (more hedges taken for cars), under the 0.80 asked for
LEVEL_MIN_TILT_DEG = 2.2
#: ... and whose sensor is at least this high above that plane (m): a plane a few centimetres below
#: the sensor is the bench it stands on (the shared Hesai/Velodyne sample sweeps: 5-7 cm, tilted
#: 3-9 deg), not the ground the detectors measure heights from
LEVEL_MIN_HEIGHT_M = 0.3
#: sweeps whose range noise sets a stream's (:meth:`OnlineDetector.range_sigma`)
NOISE_SWEEPS = 3
#: ... on every this many rings (an HDL-64 sweep still gives some 15,000 triples)
NOISE_ROW_STRIDE = 4
#: beams below and above the returns whose vegetation calls are judged again over the noise baseline that
#: the classifier's run of each column spans (:meth:`OnlineDetector.noise_regime_codes`)
RUN_MARGIN = 6
#: columns each way across which :meth:`OnlineDetector.ring_relabel` looks for a ring's next returns
#: (:func:`~prc_slam.online.noise.ring_surface`'s ``max_offset``)
RING_MAX_OFFSET = 4

log = logging.getLogger("prc_slam.online")


@njit(cache=True, nogil=True)
def overlay_labels(labels, ground, column, curb, car):
    """Sec. 8's overwriting of the coarse classes ``labels`` (rows, cols; in place), in one pass: ground
    (``ground`` or ``column``, the column ground), then curb, then vehicle where no curb is."""
    rows, cols = labels.shape
    for r in range(rows):
        for c in range(cols):
            if curb[r, c]:
                labels[r, c] = 66
            elif car[r, c]:
                labels[r, c] = 65
            elif ground[r, c] or column[r, c]:
                labels[r, c] = 2


@dataclass
class OnlineResult:
    """One scan's detector output."""

    labels: np.ndarray  # uint8 (rows, cols)
    coarse: CoarseResult
    curb_polylines: list[np.ndarray] = field(default_factory=list)
    car_boxes: list[dict] = field(default_factory=list)
    car_instances: np.ndarray | None = None
    ground_height: float | None = None
    seconds: float = 0.0
    pose: np.ndarray | None = None  # (4, 4) world-from-sensor pose used for the world-frame outputs
    car_boxes_world: list[dict] = field(default_factory=list)
    curb_polylines_world: list[np.ndarray] = field(default_factory=list)


def default_coarse_params(scan: Scan) -> CoarseParams:
    """The paper's coarse classifier, except on profilers: there signed angles are taken over
    at least 0.1 m centred on the return (``min_step``, ``centred``), since a dense profile's
    ~1 cm point spacing equals its range noise. Measured on 12 simulated profiler-urban blocks
    (everything else at its default): ground recall 0.06 -> 0.73, vehicle recall 0.09 -> 0.94,
    curb recall 0.68 -> 0.81. On 20 hdl64 sweeps it would erase the curbs (curb recall
    0.32 -> 0.01), so spinning sensors keep the paper's successive differences."""
    return CoarseParams(min_step=0.1, centred=True) if isinstance(scan.sensor, ProfilerSensor) else CoarseParams()


class OnlineDetector:
    """Streaming detectors; the ground height estimate carries over from scan to scan.

    The curb and car algorithms measure heights from the dominant ground height ``z_d``.
    ``per_line_height=True`` takes each scan line's own ``z_i`` instead (Sec. 5: "the height
    z_i of the ground at each scanline"; lines without ground take the last updated ``z_d``).
    ``z_i``, the mean of a run's 5 lowest returns, sits in the noise and gutters below the road:
    on 12 simulated profiler-urban blocks vehicle precision falls 0.976 -> 0.960 with it
    (another street: 0.974 -> 0.964), recall and curbs unchanged.

    ``column_ground_all`` (spinning path only): the ground labels of every spinning sensor also
    take the column ground of :func:`~prc_slam.online.spinning.column_ground` (Sec. 5 (b) with one
    estimate per column, the returns continuing it while they stay within a slope of the last ground
    return) beside Sec. 5 (a)'s runs of 10 horizontal returns, grown while their line angles stay
    within 10 deg: a column's ground returns lie ``range x beam gap`` apart, 9 cm at 3 m on an
    OS0-128, where 3 cm of range noise turns the line angles by tens of degrees and the run stops
    (os0-128 street ground recall 0.27). The curb and car steps keep Sec. 5's ground and heights
    (their local ground from the column ground found more simulated cars but called hedges and
    structures cars on real sweeps).

    ``noise_labels`` (spinning path only): returns, other than ground, that the coarse classifier
    calls vegetation where their column spacing (``range x beam gap``) lies under the baseline the
    sweep's range noise asks for (:mod:`prc_slam.online.noise`: the noise turns the paper's successive
    steps by more than the classifier's state spread, ``veg_sigma``) take the classes of the classifier
    with its steps taken over that baseline; car bodies beside a fine-beam sensor came out as vegetation
    (False: the paper's classes everywhere).

    ``ring_labels`` (spinning path only): vegetation returns whose column does not resolve the surface
    (``range x beam gap`` over ``SpinningCarParams.veg_resolution``: a handful of returns per column,
    each near an edge) but which lie on a smooth surface along their ring become horizontal or vertical
    (:meth:`ring_relabel`).

    ``curb_faces``: keyword arguments of :func:`~prc_slam.online.spinning.detect_curbs_spinning`
    (``relative=False, top_tol=-1``: its steps in metres, as before they were scaled to the beam spacing).
    """

    def __init__(
        self,
        coarse: CoarseParams | None = None,
        ground: GroundParams | None = None,
        curb: CurbParams | None = None,
        car: CarParams | None = None,
        per_line_height: bool = False,
        spinning: SpinningCarParams | None = None,
        spinning_path: bool = True,
        spinning_curbs: bool = True,
        level: bool = True,
        column_ground_all: bool = True,
        curb_faces: dict[str, Any] | None = None,
        noise_labels: bool = True,
        ring_labels: bool = True,
    ) -> None:
        self.level = level
        self.levelled: bool | None = None  # whether this stream is levelled (set by its first ground plane)
        self.levelling: np.ndarray | None = None  # the last levelled sweep's rotation
        self.coarse_params = coarse
        self.curb_params = curb or CurbParams()
        self.car_params = car or CarParams()
        self.ground = GroundDetector(ground)
        self.per_line_height = per_line_height
        self.spinning_params = spinning or SpinningCarParams()
        self.spinning_path = spinning_path
        self.spinning_curbs = spinning_curbs
        self.column_ground_all = column_ground_all
        self.curb_faces = dict(curb_faces or {})
        self.noise_labels = noise_labels
        self.ring_labels = ring_labels
        self.range_sigmas: list[float] = []  # the first sweeps' range noise (noise_regime_codes)
        self._default_coarse: dict[bool, CoarseParams] = {}  # default_coarse_params, per profiler or not

    @classmethod
    def paper(cls) -> OnlineDetector:
        """The paper's readings throughout: successive differences on every sensor, one PC
        per line after its final ground return, range-image regions without a distance gate or
        height floor, car returns down to the ground, the curb correction only on lines that
        see the curb, and each line's own ground height. (Profiler lines still start within
        ``coarse.PROFILER_START_RADIUS``: our reading of lines that "start at the ground".)"""
        return cls(
            CoarseParams(),
            curb=CurbParams(last_only=True, max_gap=float("inf"), min_height=0.0, max_spacing=float("inf")),
            car=CarParams(min_above_ground=0.0, curb_bridge=0.0),
            per_line_height=True,
            spinning_path=False,
            level=False,
        )

    def coarse_for(self, scan: Scan) -> CoarseParams:
        """The coarse classifier's parameters for ``scan``: the detector's own, else
        :func:`default_coarse_params` (made once per kind of sensor, not at every use in every sweep)."""
        if self.coarse_params is not None:
            return self.coarse_params
        profiler = isinstance(scan.sensor, ProfilerSensor)
        if profiler not in self._default_coarse:
            self._default_coarse[profiler] = default_coarse_params(scan)
        return self._default_coarse[profiler]

    def range_sigma(self, scan: Scan) -> float:
        """The stream's range noise (m, :func:`~prc_slam.online.noise.range_noise`): the median of
        the estimates of its first :data:`NOISE_SWEEPS` sweeps (a property of the sensor; NaN
        until a sweep gives one)."""
        if len(self.range_sigmas) < NOISE_SWEEPS:
            sigma = range_noise(scan.ranges, row_stride=NOISE_ROW_STRIDE)
            if np.isfinite(sigma):
                self.range_sigmas.append(sigma)
        return float(np.median(self.range_sigmas)) if self.range_sigmas else float("nan")

    def noise_regime_codes(
        self, scan: Scan, coarse: CoarseResult, ground: np.ndarray, regimes_deg: tuple[float, ...]
    ) -> tuple[list[np.ndarray], np.ndarray] | None:
        """The returns of a spinning sweep that the coarse classifier calls vegetation (other than
        ground) in the range-noise regime of each of ``regimes_deg`` (column spacing under
        ``noise_baseline(sigma, angle)``: there the paper's successive steps up a column are turned that
        far by the noise, and the call may be the noise's), as flat slot indices (image order) per regime,
        and the coarse classes of every slot (flat) with the steps of those returns' columns taken over
        the baseline the classifier's state spread asks for (``noise_baseline(sigma, veg_sigma)`` as
        ``CoarseParams.min_step``, centred; other columns 0). Only those columns are classified again (on
        the simulated hdl64 urban sweeps a few per cent of them). None when no such return or the noise
        is unknown."""
        params = self.coarse_for(scan)
        sigma = self.range_sigma(scan)
        baseline = noise_baseline(sigma, params.veg_sigma)
        if baseline <= params.min_step:
            return None
        bounds = [noise_baseline(sigma, angle) for angle in regimes_deg]
        if not bounds:
            return None
        # one pass over the image for every regime: the returns under the widest baseline, and their spacings
        slots, spacing = coarse_vegetation_spacing(
            coarse.codes, ground, scan.ranges, beam_gaps(scan.sensor.altitude), max(bounds), L.VEGETATION
        )
        if len(slots) == 0:
            return None
        base = dataclasses.replace(params, min_step=baseline, centred=True)
        codes = coarse_classify(scan, base, t_prime=False, lines=self._column_runs(scan, coarse, slots)).codes
        return [slots[spacing < bound] for bound in bounds], codes.ravel()

    @staticmethod
    def _column_runs(scan: Scan, coarse: CoarseResult, slots: np.ndarray) -> np.ndarray:
        """The runs of the columns of ``slots`` (flat indices; a spinning sensor's scan line i is its
        column i, lowest beam first: :func:`~prc_slam.online.coarse.scan_lines`) from :data:`RUN_MARGIN`
        beams below the lowest such slot to as many above the highest, ``-1``-padded
        (:func:`~prc_slam.online.noise.column_runs`): what the classifier needs to judge those slots again
        (its CUSUM settles within a few returns)."""
        rank = np.empty(scan.shape[0], np.int64)
        rank[np.argsort(scan.sensor.altitude, kind="stable")] = np.arange(scan.shape[0])
        return column_runs(coarse.lines, rank, slots, RUN_MARGIN)

    def ring_relabel(self, scan: Scan, labels: np.ndarray, coarse: CoarseResult) -> None:
        """Vegetation returns (``labels``, in place) that their column does not resolve and that lie
        on a smooth surface along their ring become horizontal or vertical by their signed angle
        (:func:`~prc_slam.online.noise.ring_surface`; ``ring_labels``)."""
        slots = labelled_over_spacing(
            labels, scan.ranges, beam_gaps(scan.sensor.altitude), self.spinning_params.veg_resolution, L.VEGETATION
        )
        if len(slots) == 0:
            return
        params = self.coarse_for(scan)
        baseline = noise_baseline(self.range_sigma(scan), params.veg_sigma)
        r, c = np.divmod(slots, scan.shape[1])
        cos_turn = float(np.cos(np.radians(HALFWAY_DEG)))
        smooth = ring_smooth_at(scan.slot_xyz(), scan.valid, scan.ranges, baseline, cos_turn, r, c, RING_MAX_OFFSET)
        r, c = r[smooth], c[smooth]
        labels[r, c] = np.where(np.abs(coarse.sv[r, c]) < HALFWAY_DEG, L.VERTICAL, L.HORIZONTAL)

    def level_sweep(self, scan: Scan) -> tuple[Scan, np.ndarray | None]:
        """The sweep with its slot coordinates turned so that its ground is level, and the
        rotation; or the sweep as it is and None when the stream is not levelled. Beyond the
        paper, whose detectors take the sensor's z as up. The first sweep with a ground plane
        below the sensor (PRC's column ground's :func:`~prc_slam.prc.ground.ground_plane`)
        decides for the stream: levelled when it tilts more than :data:`LEVEL_MIN_TILT_DEG` with
        the sensor :data:`LEVEL_MIN_HEIGHT_M` or more above it (decided once: the ground height
        the detectors carry from sweep to sweep must not switch frames). A levelled stream takes
        every sweep's own plane (a vehicle pitches on slopes), or the last one when a sweep has
        none. Labels are per slot and need no turning back; car boxes and curb polylines are
        turned back by :meth:`process` (a box stays upright in the levelled frame)."""
        if self.levelled is False:
            return scan, None
        xyz, valid = scan.slot_xyz(), scan.ranges > 0
        try:
            plane, _ = ground_plane(xyz, valid, beam_order(xyz, valid, scan.sensor.altitude))
            if self.levelled is None:
                tilt = float(np.degrees(np.arccos(np.clip(plane[2], -1.0, 1.0))))
                self.levelled = tilt > LEVEL_MIN_TILT_DEG and float(plane[3]) >= LEVEL_MIN_HEIGHT_M
                if self.levelled:
                    log.warning(
                        "%s: the ground tilts %.1f deg from the points' z axis (a tilted mount or frame?): the online "
                        "detectors level every sweep on its ground plane",
                        scan.source,
                        tilt,
                    )
            if self.levelled:
                self.levelling = levelling_rotation(plane[:3])
        except GroundModelError:
            pass  # undecided, or the last sweep's plane
        R = self.levelling if self.levelled else None
        if R is None:
            return scan, None
        level = (xyz.reshape(-1, 3).astype(np.float64) @ R.T).astype(np.float32).reshape(xyz.shape)
        return dataclasses.replace(scan, xyz=level), R

    def process(self, scan: Scan, pose: np.ndarray | None = None) -> OnlineResult:
        """Label every slot of ``scan``.

        Car boxes and curb polylines come in the sensor frame and, given the sensor's world pose
        ``pose`` (4 x 4; default the scan's ``gt_pose``), also in the world frame
        (``car_boxes_world``, ``curb_polylines_world``; empty without a pose).
        """
        t0 = time.perf_counter()
        R = None
        if self.level and isinstance(scan.sensor, SpinningSensor):
            scan, R = self.level_sweep(scan)
        spinning = self.spinning_path and isinstance(scan.sensor, SpinningSensor)
        # T' only for the per-column car algorithm (a spinning sensor always takes the spinning path)
        coarse = coarse_classify(scan, self.coarse_for(scan), t_prime=not spinning)
        ground = self.ground.process(scan, coarse)
        heights = self.ground.line_heights if self.per_line_height else self.ground.height
        line_heights = self.ground.line_heights
        column = None  # the ground labels' column ground (column_ground_all), made beside the cars
        noisy = None  # ([car test's, labels' regime slots as switched on], flat codes over the noise baseline)
        more_ground = self.column_ground_all
        if spinning and line_heights is None:  # columns too short for Sec. 5 (a): the column profile
            ground, line_heights, heights = column_ground(scan, coarse.lines)
            more_ground = False
            if self.per_line_height:
                heights = line_heights
        if spinning and line_heights is not None:
            lines = coarse.lines
            # each slot's ground: the last ground return below it
            zg = local_ground(lines, ground.ravel(), scan.slot_xyz64()[:, 2], line_heights)

            def all_curbs() -> CurbResult:  # Sec. 6, and the curb faces of a spinning sensor
                curbs = detect_curbs(scan, coarse, ground, heights, self.curb_params)
                if self.spinning_curbs:
                    face, polylines = detect_curbs_spinning(scan, lines, ground, line_heights, zg=zg, **self.curb_faces)
                    curbs.mask |= face
                    curbs.polylines = curbs.polylines + polylines
                return curbs

            def spinning_cars() -> SpinningCars:
                nonlocal noisy
                sp = self.spinning_params
                gap = (
                    float(np.degrees(np.median(np.abs(np.diff(np.sort(scan.sensor.altitude))))))
                    if scan.shape[0] > 1
                    else 0.0
                )
                if sp.vegetation_noise or self.noise_labels:
                    veg_sigma = self.coarse_for(scan).veg_sigma
                    regimes = (sp.vegetation_regime,) * sp.vegetation_noise + (veg_sigma,) * self.noise_labels
                    noisy = self.noise_regime_codes(scan, coarse, ground, regimes)
                if sp.vegetation_noise:  # step 6's vegetation share (spinning.py) over the noise baseline
                    veg = coarse.codes == L.VEGETATION
                    if noisy is not None:
                        veg.ravel()[noisy[0][0]] = noisy[1][noisy[0][0]] == L.VEGETATION
                elif sp.vegetation_step > 0 and gap < sp.vegetation_gap:
                    veg_params = CoarseParams(min_step=sp.vegetation_step, centred=True)
                    veg = coarse_classify(scan, veg_params, t_prime=False).codes == L.VEGETATION
                else:
                    veg = coarse.codes == L.VEGETATION
                if R is not None and sp.missing_top:  # a levelled sweep's beams no longer point at the sensor's
                    sp = dataclasses.replace(sp, missing_top=False)  # elevations: where they meet the ground is unknown
                return detect_cars_spinning(scan, ground, lines, line_heights, veg, sp, zg)

            def curbs_and_column() -> tuple[CurbResult, np.ndarray | None]:
                col = column_ground(scan, lines)[0] if more_ground else None
                return all_curbs(), col

            (cars, (curbs, column)), _ = side_by_side(spinning_cars, curbs_and_column)  # cars use neither
        else:
            curbs = detect_curbs(scan, coarse, ground, heights, self.curb_params)
            cars = detect_cars(scan, coarse, heights, curbs.mask, self.car_params)
        if R is not None:  # boxes and polylines back into the sensor's frame
            curbs.polylines = [(p.astype(np.float64) @ R).astype(np.float32) for p in curbs.polylines]
            for b in cars.boxes:
                b["center"] = (R.T @ np.asarray(b["center"], dtype=np.float64)).tolist()
        self.last_cars = cars
        assert L.GROUND == 2 and L.CURB == 66 and L.VEHICLE == 65  # codes written by overlay_labels
        labels = coarse.codes.copy()
        if self.noise_labels and noisy is not None:
            labels.ravel()[noisy[0][-1]] = noisy[1][noisy[0][-1]]
        if spinning and self.ring_labels:
            self.ring_relabel(scan, labels, coarse)
        overlay_labels(labels, ground, ground if column is None else column, curbs.mask, cars.mask)
        zd = self.ground.height if self.ground.height is not None else (heights if np.isscalar(heights) else None)
        seconds = time.perf_counter() - t0
        pose = scan.gt_pose if pose is None else np.asarray(pose, dtype=np.float64)
        result = OnlineResult(labels, coarse, curbs.polylines, cars.boxes, cars.instances, zd, seconds, pose)
        if pose is not None:
            if pose.shape != (4, 4) or not np.isfinite(pose).all():
                raise ValueError(f"{scan.source}: pose must be a finite 4 x 4 matrix, got shape {pose.shape}")
            result.car_boxes_world = boxes_to_world(cars.boxes, pose)
            result.curb_polylines_world = [p @ pose[:3, :3].T.astype(np.float32) + pose[:3, 3] for p in curbs.polylines]
        return result


def boxes_to_world(boxes: list[dict], pose: np.ndarray) -> list[dict]:
    """Oriented boxes (centre, size, yaw about the sensor's z) moved into the world frame by
    ``pose``; the yaw gains the pose's heading (boxes stay upright: the roll and pitch of a
    vehicle-mounted sensor are small, and the viewer draws boxes about the world's z)."""
    rot, t = pose[:3, :3], pose[:3, 3]
    heading = float(np.arctan2(rot[1, 0], rot[0, 0]))
    out = []
    for b in boxes:
        w = dict(b)
        w["center"] = (rot @ np.asarray(b["center"], dtype=np.float64) + t).tolist()
        w["yaw"] = float(np.arctan2(np.sin(b["yaw"] + heading), np.cos(b["yaw"] + heading)))
        out.append(w)
    return out
