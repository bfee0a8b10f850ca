"""The Rerun sink: every stage of a run, on a ``frame`` sequence timeline and a ``sensor_time``
timeline.

Entity paths::

    world                         ViewCoordinates (right-handed, z up), static
    world/sensor                  Transform3D: estimated sensor pose
    world/sensor/raw              Points3D, every input point, class ids = PRC labels
    world/sensor/filtered         Points3D, what KISS-ICP got
    world/map                     Points3D, KISS-ICP's local map (thinned)
    world/trajectory/estimate     LineStrips3D, estimated positions so far (main variant)
    world/trajectory/ground_truth LineStrips3D, when known
    world/trajectory/variants/V   LineStrips3D, one strip per variant in comparisons
    range_image/range             DepthImage (metres)
    range_image/prc               SegmentationImage of PRC labels
    range_image/online            SegmentationImage of the online detectors' labels
    range_image/car_instances     SegmentationImage of the car instance ids
    world/sensor/online           Points3D, every point, class ids = online detector labels
    world/detections/curbs        LineStrips3D, one polyline per detected curb
    world/detections/cars         Boxes3D, one oriented box per car instance, labelled
    metrics/ms/V/stage            Scalars: ms per stage and variant
    metrics/points/..., metrics/points_to_icp/V, metrics/inliers/V   Scalars: points in / kept per
                                  class, points registered, ICP inliers
    metrics/icp_threshold/V, metrics/icp/V/...    Scalars: adaptive threshold, inlier fraction, residual,
                                  divergence flag
    metrics/error/position_m      Scalars: position error against the ground truth
    metrics/degeneracy/V          Scalars: the registration's conditioning (smallest over largest
                                  information; below odometry.degeneracy.ratio a direction is degenerate)
    world/map_classified/part_N   Points3D, a classified map (shifted to a display origin when
                                  geo-referenced: :attr:`RerunSink.map_origin`, in the text log)
    logs                          TextLog: warnings and skips

One AnnotationContext (the label codes, names and colours of ``prc_slam.labels``) at the root
and a default blueprint (3-D view, range images, time series, text log).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from prc_slam import labels as L

#: coordinates beyond this (m) lose more than a millimetre in float32 (its spacing there is 1 mm)
FLOAT32_EXACT_M = 1.0e4


def display_origin(points: np.ndarray, step: float = 100.0) -> np.ndarray:
    """Where to put the origin of a cloud shown in float32: zero when every coordinate is within
    :data:`FLOAT32_EXACT_M`, else the median point rounded to ``step`` metres (geo-referenced
    clouds: UTM eastings ~5e5 m and northings ~5e6 m are 0.03 and 0.5 m apart in float32)."""
    points = np.asarray(points, dtype=np.float64)
    if not len(points) or np.abs(points).max() <= FLOAT32_EXACT_M:
        return np.zeros(3)
    return np.round(np.median(points, axis=0) / step) * step


@dataclass
class VizConfig:
    """What to log and how often.

    Attributes
    ----------
    every : int
        Log clouds and images on every ``every``-th frame (poses, trajectories and metrics on
        every frame). The default keeps a 1000-frame hdl64 recording under 1 GB.
    map_every : int
        Log the local map on every ``map_every``-th frame.
    map_voxel : float
        Thin the logged map to one point per voxel of this size (m).
    """

    every: int = 5
    map_every: int = 20
    map_voxel: float = 0.5
    main_variant: str = "prc"
    variants: list[str] = field(default_factory=list)


def annotation_context() -> rr.AnnotationContext:
    """Label codes, names and colours of DESIGN.md."""
    return rr.AnnotationContext([rr.AnnotationInfo(id=i.code, label=i.name, color=i.color) for i in L.LABELS])


def default_blueprint() -> rrb.Blueprint:
    """3-D view beside the range images, three time series with their own axes (stage times in
    ms; points per class; ICP threshold and position error in m) and the text log."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="world", origin="world"),
            rrb.Vertical(
                rrb.Spatial2DView(name="range", origin="range_image/range"),
                rrb.Spatial2DView(name="PRC labels", origin="range_image", contents=["range_image/prc"]),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="stage times (ms)", origin="metrics/ms"),
                    rrb.TimeSeriesView(
                        name="points",
                        origin="metrics",
                        contents=["metrics/points/**", "metrics/points_to_icp/**", "metrics/inliers/**"],
                    ),
                    rrb.TimeSeriesView(
                        name="ICP threshold, error (m)",
                        origin="metrics",
                        contents=["metrics/icp_threshold/**", "metrics/error/**", "metrics/icp/**"],
                    ),
                ),
                rrb.TextLogView(name="log", origin="logs"),
                row_shares=[1, 1, 3, 1],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _thin_index(points: np.ndarray, voxel: float) -> np.ndarray:
    """Indices of the first point in every voxel (all points when ``voxel`` is 0)."""
    if len(points) == 0 or voxel <= 0:
        return np.arange(len(points))
    v = np.floor(points / voxel).astype(np.int64) & 0x1FFFFF  # 21 bits per axis
    keys = (v[:, 0] << 42) | (v[:, 1] << 21) | v[:, 2]
    _, first = np.unique(keys, return_index=True)
    return np.sort(first)


def _thin(points: np.ndarray, voxel: float) -> np.ndarray:
    return points[_thin_index(points, voxel)]


class RerunSink:
    """Receives the pipeline's per-frame records and logs them.

    Parameters
    ----------
    recording : rr.RecordingStream
        Where to log (a file, a viewer, a web viewer; see :func:`open_recording`).
    config : VizConfig
    """

    def __init__(self, recording: rr.RecordingStream, config: VizConfig | None = None) -> None:
        self.rec = recording
        self.config = config or VizConfig()
        self._positions: dict[str, list[np.ndarray]] = {}
        self._gt: list[np.ndarray] = []
        self._pose: np.ndarray | None = None
        #: subtracted from every classified-map point before logging (:func:`display_origin`)
        self.map_origin: np.ndarray | None = None
        #: called before each frame is logged; raises when the viewer logged to has gone
        #: (:class:`ViewerError`), so that the stream never waits for it forever
        self.check: Callable[[], None] | None = None
        self.rec.log("/", annotation_context(), static=True)
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def current_pose(self) -> np.ndarray | None:
        """The main variant's pose of the last logged frame, in the logged world frame."""
        return self._pose

    def warn(self, message: str) -> None:
        """A warning or a skip in the text log."""
        self.rec.log("logs", rr.TextLog(message, level=rr.TextLogLevel.WARN))

    def _time(self, index: int, t: float) -> None:
        if self.check is not None:
            self.check()
        self.rec.set_time("frame", sequence=index)
        self.rec.set_time("sensor_time", duration=float(t))

    def log_classified(self, index: int, scan, labels: np.ndarray, t: float | None = None) -> None:
        """A scan with its PRC labels (slots): raw cloud and range images."""
        self._time(index, t if t is not None else scan.meta.get("frame_time", float(index)))
        if scan.meta.get("nan_ranges"):
            self.warn(f"{scan.source}: {scan.meta['nan_ranges']} NaN ranges read as no return")
        if scan.meta.get("collisions"):
            self.rec.log(
                "logs",
                rr.TextLog(
                    f"{scan.source}: {scan.meta['collisions']} points share a range-image "
                    "slot with a nearer point and take its label",
                    level=rr.TextLogLevel.INFO,
                ),
            )
        if index % self.config.every:
            return
        pts = scan.points()
        ids = scan.per_point(labels).astype(np.uint16)
        self.rec.log("world/sensor/raw", rr.Points3D(pts, class_ids=ids, radii=0.03))
        self.rec.log("range_image/range", rr.DepthImage(scan.ranges, meter=1.0))
        self.rec.log("range_image/prc", rr.SegmentationImage(labels))

    def log_map(self, points: np.ndarray, labels: np.ndarray, part: int = 0) -> None:
        """One chunk of a classified map (paper 004), thinned to ``config.map_voxel``, static:
        ``world/map_classified/part_N`` coloured by class. Rerun stores float32 positions, which
        are 0.5 m apart at UTM northings: a map far from the origin is shown shifted by
        :attr:`map_origin` (set by the first chunk, said in the text log)."""
        points = np.asarray(points, dtype=np.float64)
        ok = np.isfinite(points).all(axis=1)
        pts, lab = points[ok], np.asarray(labels)[ok]
        if self.map_origin is None and len(pts):
            self.map_origin = display_origin(pts)
            if self.map_origin.any():
                x, y, z = self.map_origin
                self.rec.log(
                    "logs",
                    rr.TextLog(
                        f"the classified map is shown shifted by ({-x:.0f}, {-y:.0f}, {-z:.0f}) m: Rerun keeps "
                        "float32 coordinates, too coarse at these values; add them back to read positions",
                        level=rr.TextLogLevel.INFO,
                    ),
                )
        if self.map_origin is not None:
            pts = pts - self.map_origin
        keep = _thin_index(pts, self.config.map_voxel)
        pts, lab = pts[keep], lab[keep]
        self.rec.log(
            f"world/map_classified/part_{part}",
            rr.Points3D(pts, class_ids=lab.astype(np.uint16), radii=0.05),
            static=True,
        )

    def log_online(self, index: int, scan, result, pose: np.ndarray | None = None) -> None:
        """Online detector output: ``range_image/online``, the detector labels of every point
        (``world/sensor/online``), ``world/detections/curbs`` (polylines) and
        ``world/detections/cars`` (oriented boxes with instance labels), in the world frame given
        ``pose`` (else the sensor frame)."""
        self._time(index, scan.meta.get("frame_time", float(index)))
        if index % self.config.every:
            return
        self.rec.log("range_image/online", rr.SegmentationImage(result.labels))
        if result.car_instances is not None:
            self.rec.log("range_image/car_instances", rr.SegmentationImage(np.asarray(result.car_instances)))
        ids = scan.per_point(result.labels).astype(np.uint16)
        self.rec.log("world/sensor/online", rr.Points3D(scan.points(), class_ids=ids, radii=0.03))
        pose = np.eye(4) if pose is None else pose
        rot, t = pose[:3, :3], pose[:3, 3]
        strips = [p @ rot.T + t for p in result.curb_polylines]
        self.rec.log("world/detections/curbs", rr.LineStrips3D(strips, colors=[L.color_lut()[L.CURB]]))
        boxes = result.car_boxes
        centers = np.array([b["center"] for b in boxes]).reshape(-1, 3) @ rot.T + t
        yaw0 = float(np.arctan2(rot[1, 0], rot[0, 0]))
        quats = [
            rr.Quaternion(xyzw=[0.0, 0.0, np.sin((b["yaw"] + yaw0) / 2), np.cos((b["yaw"] + yaw0) / 2)]) for b in boxes
        ]
        self.rec.log(
            "world/detections/cars",
            rr.Boxes3D(
                centers=centers,
                sizes=np.array([b["size"] for b in boxes]).reshape(-1, 3),
                quaternions=quats,
                labels=[f"car {i + 1}" for i in range(len(boxes))],
                class_ids=np.full(len(boxes), L.VEHICLE, np.uint16),
            ),
        )

    def log_record(self, record, gt_pose: np.ndarray | None = None) -> None:
        """One frame of an odometry comparison (:class:`prc_slam.odometry.compare.FrameRecord`).

        Every frame: the sensor pose, stage timings, ICP thresholds and the position error.
        Every ``config.every``-th frame: clouds, range images, trajectories and class counts.
        """
        frame = record.frame
        scan = frame.scan
        i = record.index
        full = i % self.config.every == 0
        main = self.config.main_variant if self.config.main_variant in record.poses else next(iter(record.poses))
        labels = frame.labels if frame.labels is not None else np.full(scan.shape, L.UNCLASSIFIED, np.uint8)
        self.log_classified(i, scan, labels)
        if gt_pose is not None:
            if not self._gt:
                self._first_gt = gt_pose
            self._gt.append(gt_pose[:3, 3])
        world_from_first = self._first_gt if self._gt else np.eye(4)
        for name, pose in record.poses.items():
            p = world_from_first @ pose
            self._positions.setdefault(name, []).append(p[:3, 3])
            if name == main:
                self._pose = p
                self.rec.log("world/sensor", rr.Transform3D(translation=p[:3, 3], mat3x3=p[:3, :3]))
                if gt_pose is not None:
                    err = float(np.linalg.norm(p[:3, 3] - gt_pose[:3, 3]))
                    self.rec.log("metrics/error/position_m", rr.Scalars(err))
            for stage, ms in record.ms(name).items():
                self.rec.log(f"metrics/ms/{name}/{stage}", rr.Scalars(ms))
            self.rec.log(f"metrics/icp_threshold/{name}", rr.Scalars(record.runs[name].odometry.threshold))
            if hasattr(record, "health"):  # registration health and the divergence flag
                h = record.health(name)
                for key in ("inliers", "inlier_fraction", "mean_residual_m", "suspicious"):
                    if h[key] is not None and np.isfinite(float(h[key])):
                        # counts beside the point counts; fractions, metres and the flag on the ICP axis
                        path = f"metrics/inliers/{name}" if key == "inliers" else f"metrics/icp/{name}/{key}"
                        self.rec.log(path, rr.Scalars(float(h[key])))
            conditioning = getattr(record.runs[name].odometry, "conditioning", None)
            if conditioning and conditioning[-1] is not None:  # smallest / largest information (odometry.degeneracy)
                self.rec.log(f"metrics/degeneracy/{name}", rr.Scalars(conditioning[-1].ratio))
        if full:
            self._log_trajectories(main)
            self._log_clouds(record, main, world_from_first)

    def _log_trajectories(self, main: str) -> None:
        if self._gt:
            self.rec.log("world/trajectory/ground_truth", rr.LineStrips3D([np.array(self._gt)], colors=[(0, 0, 0)]))
        for name, positions in self._positions.items():
            strip = rr.LineStrips3D([np.array(positions)])
            self.rec.log(f"world/trajectory/variants/{name}", strip)
            if name == main:
                self.rec.log("world/trajectory/estimate", strip)

    def _log_clouds(self, record, main: str, world_from_first: np.ndarray) -> None:
        frame = record.frame
        scan = frame.scan
        kept = record.kept[main]
        codes = frame.point_labels() if frame.labels is not None else None
        ids = None if codes is None else codes[kept].astype(np.uint16)
        self.rec.log("world/sensor/filtered", rr.Points3D(scan.points()[kept], class_ids=ids, radii=0.04))
        if record.index % self.config.map_every == 0:
            world_map = _thin(record.runs[main].odometry.local_map_points(), self.config.map_voxel)
            world_map = world_map @ world_from_first[:3, :3].T + world_from_first[:3, 3]
            self.rec.log("world/map", rr.Points3D(world_map, colors=[(150, 150, 150)], radii=0.05))
        for name in record.poses:
            self.rec.log(f"metrics/points_to_icp/{name}", rr.Scalars(float(record.kept[name].sum())))
        if codes is not None:
            n_in = np.bincount(codes, minlength=256)
            n_kept = np.bincount(codes[kept], minlength=256)
            for c in np.flatnonzero(n_in):
                name = L.CODE_TO_NAME.get(int(c), f"code_{c}")
                self.rec.log(f"metrics/points/{name}/in", rr.Scalars(float(n_in[c])))
                self.rec.log(f"metrics/points/{name}/kept", rr.Scalars(float(n_kept[c])))


#: where everything served listens unless ``--bind`` says otherwise
LOOPBACK = "127.0.0.1"
#: seconds a started viewer or web viewer has to listen on its port
START_TIMEOUT_S = 20.0
#: seconds a spawned viewer must stay up after it listens (it opens its window then, and ends
#: at once when there is no display to open it on)
SETTLE_S = 1.5


class ViewerError(OSError):
    """The Rerun viewer could not be started, or ended while the run logged to it."""


def has_display() -> bool:
    """Whether a desktop window can be opened: always on macOS and Windows; elsewhere when
    ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set."""
    if sys.platform == "darwin" or os.name == "nt":
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def is_loopback(address: str) -> bool:
    """Whether ``address`` (an IP or host name) is this machine's loopback only."""
    import ipaddress

    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False


def rerun_executable(python: str | None = None, path: str | None = None) -> str | None:
    """The Rerun viewer executable, found without the virtual environment being activated.

    In order: the binary shipped in rerun-sdk's ``rerun_cli`` package (the real program, not the
    Python wrapper that would start it as a second process), ``rerun`` beside the interpreter
    ``python`` (default ``sys.executable``: ``.venv/bin/rerun``, not on ``PATH`` when the
    environment is not activated), the interpreter's scripts directory, then ``path`` (default
    ``PATH``). None when there is none.
    """
    import importlib.util
    import shutil
    import sysconfig

    name = "rerun.exe" if os.name == "nt" else "rerun"
    candidates: list[Path] = []
    if python is None:  # this interpreter: rerun-sdk's own binary first
        python = sys.executable
        spec = importlib.util.find_spec("rerun_cli")
        if spec is not None and spec.origin:
            candidates.append(Path(spec.origin).parent / name)
    candidates.append(Path(python).parent / name)  # not resolved: the venv's bin, not the base interpreter's
    candidates.append(Path(sysconfig.get_path("scripts")) / name)
    for candidate in candidates:
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    return shutil.which(name, path=path)


def _listening(port: int, host: str = LOOPBACK) -> bool:
    """Whether something accepts TCP connections on ``host:port``."""
    import socket

    connect_to = LOOPBACK if host in ("0.0.0.0", "") else "::1" if host == "::" else host
    try:
        with socket.create_connection((connect_to, port), timeout=0.5):
            return True
    except OSError:
        return False


def _last_line(log_file) -> str:
    """The last non-empty line a started viewer wrote (its error), without terminal colours."""
    import re

    log_file.seek(0)
    text = log_file.read().decode(errors="replace")
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in text.splitlines()]
    lines = [line for line in lines if line]
    return lines[-1] if lines else "no message"


def _linux_die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    import ctypes
    import signal

    ctypes.CDLL(None).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG


def start_viewer(args: list[str], port: int, what: str, detach: bool, host: str = LOOPBACK):
    """Start the Rerun executable with ``args`` and wait until it listens on ``port``; raises
    :class:`ViewerError` naming ``what`` (and the viewer's own last line) when it is missing or
    ends first. ``detach``: the viewer gets a session of its own and outlives this process (a
    desktop viewer); else it ends with this process (a web viewer server)."""
    import subprocess
    import tempfile

    exe = rerun_executable()
    if exe is None:
        raise ViewerError(
            f"{what}: the Rerun viewer executable 'rerun' was not found beside {sys.executable} nor on PATH "
            "(reinstall rerun-sdk); use --rrd FILE and open it later"
        )
    log_file = tempfile.TemporaryFile()
    options: dict = {"start_new_session": True} if detach else {}
    if not detach and sys.platform.startswith("linux"):
        options["preexec_fn"] = _linux_die_with_parent
    proc = subprocess.Popen(
        [exe, *args],
        stdin=subprocess.DEVNULL,
        stdout=log_file,
        stderr=subprocess.STDOUT,
        env={**os.environ, "RERUN_APP_ONLY": "true"},
        **options,
    )
    deadline = time.monotonic() + START_TIMEOUT_S
    settled_at = None
    while True:
        code = proc.poll()
        if code is not None:
            raise ViewerError(f"{what}: the Rerun viewer ended at start (exit code {code}): {_last_line(log_file)}")
        now = time.monotonic()
        if settled_at is None and _listening(port, host):
            settled_at = now + (SETTLE_S if detach else 0.0)
        if settled_at is not None and now >= settled_at:
            return proc
        if now > deadline:
            proc.terminate()
            raise ViewerError(f"{what}: the Rerun viewer did not listen on port {port} within {START_TIMEOUT_S:g} s")
        time.sleep(0.1)


def open_recording(application: str = "prc_slam", **where) -> tuple[rr.RecordingStream, str | None]:
    """:func:`start_recording` without the processes it started (a web viewer's server ends with
    this process)."""
    rec, address, _ = start_recording(application, **where)
    return rec, address


def start_recording(
    application: str = "prc_slam",
    *,
    rrd: str | None = None,
    connect: str | None = None,
    serve_web: bool = False,
    spawn: bool = False,
    web_port: int | None = None,
    grpc_port: int | None = None,
    bind: str = LOOPBACK,
    spawn_name: str = "--spawn",
) -> tuple[rr.RecordingStream, str | None, list]:
    """A recording stream writing to any combination of a file, a running viewer and a served
    web viewer, or to a spawned desktop viewer. Returns the stream, for ``serve_web`` the
    viewer's address, and the viewer processes started (``subprocess.Popen``: a spawned desktop
    viewer, which outlives this process, or the web viewer's server, which does not).

    Everything served listens on ``bind`` (default the loopback: only this machine can connect).
    A spawned viewer is the ``rerun`` executable found by :func:`rerun_executable`; it is waited
    for, and one that ends at start (no display, a port in use) raises :class:`ViewerError` with
    its own message instead of leaving the stream to block on a viewer that is not there (the
    message names ``spawn_name``: the command or option that asked for it)."""
    rec = rr.RecordingStream(application)
    address = None
    if spawn:
        port = grpc_port or 9876
        procs = []
        if not _listening(port):  # else a viewer runs there already: log to it
            args = ["--port", str(port), "--bind", bind, "--memory-limit", "75%", "--expect-data-soon"]
            procs.append(start_viewer(args, port, spawn_name, detach=True))
        rec.set_sinks(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"), default_blueprint=default_blueprint())
        return rec, None, procs
    sinks: list = []
    if rrd is not None:
        sinks.append(rr.FileSink(rrd))
    if connect is not None:
        sinks.append(rr.GrpcSink(connect))
    if serve_web:
        server = rr.GrpcServerSink(bind_ip=bind, port=grpc_port or 9876)
        sinks.append(server)
    if not sinks:
        raise ValueError("choose at least one of rrd, connect, serve_web or spawn")
    rec.set_sinks(*sinks, default_blueprint=default_blueprint())
    procs = []
    if serve_web:
        # a browser must be sent to an address it can reach: the loopback for an unspecified bind
        uri = server.uri.replace("://0.0.0.0:", "://127.0.0.1:").replace("://[::]:", "://127.0.0.1:")
        port = web_port or 9090
        args = ["--serve-web", "--bind", bind, "--web-viewer-port", str(port), uri]
        procs.append(start_viewer(args, port, "--serve-web", detach=False, host=bind))
        host = "localhost" if bind in ("0.0.0.0", "::") or is_loopback(bind) else bind
        address = f"http://{host}:{port}/?url={uri}"
    return rec, address, procs
