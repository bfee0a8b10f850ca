"""The live loop: sweeps from a receiver through the same :class:`~prc_slam.pipeline.Pipeline` as
offline (organise → PRC → online detectors → filter → KISS-ICP) into the sinks, with latency,
rates, drops and losses measured.

A sweep's latency runs from the receipt of its last packet (the kernel's stamp) to the moment its
pose and labels are out (the poses, labels and filtered-stream files have them; the viewer's
logging follows on its own thread). Stopping (Ctrl-C, SIGTERM, ``--timeout`` without packets,
the end of a ``--realtime`` recording) ends the receiving; the sweep being processed is
finished, then every output is flushed and closed.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam.config import Config
from prc_slam.live.receiver import RealtimeReader, Sweep, SweepQueue, UdpReceiver
from prc_slam.live.sinks import RSS_EVERY, BackgroundSink, FilteredMcap, PosesFile, TimedSinks
from prc_slam.live.sources import Source
from prc_slam.pipeline import FrameError, NextFrame, Pipeline, PipelineResult

log = logging.getLogger("prc_slam")

STAGES = ("organize", "prc", "online", "filter", "icp", "sinks")


@dataclass
class LiveOptions:
    """What a live run does besides the pipeline."""

    variant: str = "prc"
    online: bool = False
    timeout: float | None = None
    queue: int = 1
    status_every: float = 1.0  # on a terminal
    log_every: float = 10.0  # in the log
    realtime_rate: float = 1.0
    max_frames: int | None = None
    model: str | None = None
    meta: Path | None = None
    fmt: str | None = None
    open_options: dict[str, Any] = field(default_factory=dict)
    receiver_process: bool = True  # Velodyne: receive and decode in a second process
    warm_up: bool = True  # compile the stages on synthetic sweeps before listening


class LivePipeline(Pipeline):
    """The offline :class:`Pipeline`, but never reading ahead: a live source's next sweep may not
    have arrived, and waiting for it would delay this one's outputs by a sweep period. The next
    frame is still made on a thread beside the registration (``odometry.overlap``) once it comes."""

    def _next_frames(self, ahead, result: PipelineResult) -> NextFrame:
        return NextFrame(self._classified(self._readable(ahead, result)), None)


class LiveSweeps(Iterator[Any]):
    """The Scans of a live source, as the queue gives them; ends when the run is stopped, on
    ``timeout`` s without packets, at the end of a recording or after ``max_frames``."""

    def __init__(self, source: Any, queue: SweepQueue, status: Status, opts: LiveOptions) -> None:
        self.source, self.queue, self.status, self.opts = source, queue, status, opts
        self.stop = threading.Event()
        self.ended_by: str | None = None
        self.taken = 0
        self.started = time.perf_counter()

    def __next__(self) -> Any:
        while True:
            if self.stop.is_set() and len(self.queue) == 0:  # the sweeps received are processed first
                self.ended_by = self.ended_by or "stopped"
                raise StopIteration
            if self.ended_by == "timeout" and len(self.queue) == 0:
                raise StopIteration
            if self.opts.max_frames is not None and self.taken >= self.opts.max_frames:
                self.ended_by = "max_frames"
                raise StopIteration
            if self.source.error is not None:  # raised by run_live once the outputs are closed
                self.ended_by = "error"
                raise StopIteration
            if self.stop.is_set():
                self.source.stop()  # receive no more
            sweep = self.queue.get(0.1)
            self.status.tick()
            if sweep is None:
                if self.queue.closed and len(self.queue) == 0:
                    self.ended_by = self.ended_by or "end of recording"
                    raise StopIteration
                last = self.source.stats.last_packet or self.started
                if self.opts.timeout is not None and time.perf_counter() - last >= self.opts.timeout:
                    if self.ended_by is None:  # the sweep being assembled is complete as it is
                        self.ended_by = "timeout"
                        log.warning(f"no packets for {self.opts.timeout:g} s (--timeout): ending the run")
                        if hasattr(self.source, "flush") and self.source.flush():
                            continue
                    raise StopIteration
                continue
            self.taken += 1
            return self._scan(sweep)

    def _scan(self, sweep: Sweep) -> Any:
        from data_tools.errors import DataError
        from prc_slam.scan import ScanError

        if isinstance(sweep.scan, Exception):
            raise FrameError(str(sweep.scan))
        try:
            scan = sweep.scan if sweep.scan is not None else self.source.assembler.scan_of(sweep)
        except (DataError, ScanError) as exc:
            raise FrameError(str(exc)) from exc
        scan.meta["live_received"] = sweep.received
        scan.meta["live_lost_packets"] = sweep.lost_packets
        scan.meta["live_flushed"] = sweep.flushed
        scan.meta["live_index"] = sweep.index
        return scan


class Status:
    """The live counters and the status line (every ``every`` s on a terminal, every ``log_every``
    s in the log)."""

    def __init__(self, source: Any, queue: SweepQueue, every: float, log_every: float) -> None:
        self.source, self.queue = source, queue
        self.every, self.log_every = every, log_every
        self.tty = sys.stderr.isatty()
        self.latency: list[float] = []
        self.out_times: list[float] = []
        self.stage_ms: dict[str, list[float]] = {k: [] for k in STAGES}
        self.lost_per_frame: list[int] = []
        self.frames = 0
        self.rss_mb: dict[str, float] = {}  # resident memory (MB) after the sweeps 50, 100, ... of the source
        self.next_rss = RSS_EVERY
        now = time.perf_counter()
        self._next_tty, self._next_log = now + every, now + log_every

    def line(self) -> str:
        st = self.source.stats
        rate_in = st.rate_in()
        lat = np.asarray(self.latency[-200:]) * 1e3
        p50, p99 = (np.percentile(lat, 50), np.percentile(lat, 99)) if len(lat) else (float("nan"),) * 2
        return (
            f"live: in {rate_in or 0:.1f} Hz, out {rate_out(self.out_times) or 0:.1f} Hz, {self.frames} sweeps, "
            f"dropped {self.queue.dropped}, lost packets {st.lost_packets}, foreign {st.foreign_packets}, "
            f"latency p50 {p50:.0f} ms p99 {p99:.0f} ms"
        )

    def tick(self) -> None:
        now = time.perf_counter()
        if self.tty and now >= self._next_tty:
            self._next_tty = now + self.every
            print(self.line(), file=sys.stderr, flush=True)
        if now >= self._next_log:
            self._next_log = now + self.log_every
            if self.tty:  # already on the terminal: the log file only
                for h in log.handlers:
                    if isinstance(h, logging.FileHandler):
                        h.emit(log.makeRecord(log.name, logging.INFO, __file__, 0, self.line(), None, None))
            else:
                log.info(self.line())


def rate_out(times: list[float]) -> float | None:
    """Sweeps per second between the first and the last output."""
    if len(times) < 2 or times[-1] <= times[0]:
        return None
    return (len(times) - 1) / (times[-1] - times[0])


@dataclass
class LiveRun:
    """What a live run produced."""

    metrics: dict[str, Any]
    written: list[Path]
    result: PipelineResult | None = None


def percentiles_ms(latency_s: list[float]) -> dict[str, float | None]:
    """``{"p50", "p95", "p99", "max"}`` of the latencies (ms; None without frames)."""
    if not latency_s:
        return {"p50": None, "p95": None, "p99": None, "max": None}
    ms = np.asarray(latency_s) * 1e3
    return {
        "p50": float(np.percentile(ms, 50)),
        "p95": float(np.percentile(ms, 95)),
        "p99": float(np.percentile(ms, 99)),
        "max": float(ms.max()),
    }


def open_source(source: Source, queue: SweepQueue, opts: LiveOptions) -> Any:
    """The receiver thread of ``source`` (bound, not started)."""
    if source.kind == "velodyne":
        from prc_slam.live.receiver import ProcessReceiver, VelodyneAssembler, is_velodyne_data

        if opts.receiver_process:
            rx = ProcessReceiver(source.host, source.port, str(source), opts.model, queue)
        else:
            assembler = VelodyneAssembler(str(source), opts.model)
            rx = UdpReceiver(source.host, source.port, assembler, is_velodyne_data, queue)
        rx.bind()
        return rx
    if source.kind == "ouster":
        from prc_slam.live.ouster import OusterAssembler

        assembler = OusterAssembler(str(source), opts.meta)
        rx = UdpReceiver(source.host, source.port, assembler, assembler.accept, queue)
        rx.bind()
        return rx
    from prc_slam.jobs.common import open_input

    dataset, n = open_input(source.path, opts.fmt, opts.max_frames, **opts.open_options)
    period = getattr(getattr(dataset, "sensor", None), "sweep_period", None) or 0.1
    return RealtimeReader(dataset, n, queue, rate=opts.realtime_rate, period=period)


#: velodyne-decoder's point fields
SWEEP_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("time", "<f4"), ("column", "<u2"),
     ("ring", "u1"), ("return_type", "u1")]
)  # fmt: skip


#: car-sized boxes of the synthetic street: (x, y) of the centre, length, width, height (m)
SYNTHETIC_CARS = ((7.0, 3.5, 4.5, 1.8, 1.5), (-9.0, -3.5, 4.5, 1.8, 1.5), (12.0, -3.5, 4.8, 1.9, 1.6))


def _box_range(d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Range along the unit rays ``d`` (N, 3) from the origin to the box [lo, hi] (inf: missed)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = lo / d, hi / d
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((far >= near) & (near > 0), near, np.inf)


def synthetic_sweep(rings: int = 32, cols: int = 1000, turn: float = 0.0) -> np.ndarray:
    """A decoded Velodyne sweep (velodyne-decoder's fields) of a street: road 1.8 m below the
    sensor, 15 cm curbs 5 m to each side, parked cars, walls 8-14 m around; ``turn``: the
    sensor's yaw (rad)."""
    az = np.repeat(np.linspace(0.0, 2 * np.pi, cols, endpoint=False), rings) + turn
    ring = np.tile(np.arange(rings), cols)
    el = np.radians(np.linspace(-30.0, 10.0, rings))[ring]
    d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    wall = (11.0 + 3.0 * np.sin(3 * az)) / np.maximum(np.cos(el), 1e-6)
    road = np.where(el < 0, 1.8 / np.maximum(-np.sin(el), 1e-6), np.inf)
    walk = np.where(el < 0, 1.65 / np.maximum(-np.sin(el), 1e-6), np.inf)
    across = np.abs(np.where(np.isfinite(road), road, 0.0) * d[:, 1])
    ground = np.where(across < 5.0, road, walk)  # the curb: sidewalks beyond |y| = 5 m
    r = np.minimum(wall, ground)
    for x, y, length, width, height in SYNTHETIC_CARS:
        lo = np.array([x - length / 2, y - width / 2, -1.8])
        r = np.minimum(r, _box_range(d, lo, lo + np.array([length, width, height])))
    pts = np.zeros(len(az), dtype=SWEEP_DTYPE)
    pts["x"], pts["y"], pts["z"] = (r[:, None] * d).T
    pts["intensity"] = 50.0
    pts["time"] = np.repeat(np.arange(cols), rings) / cols * 0.1 - 0.1
    pts["column"] = np.repeat(np.arange(cols), rings)
    pts["ring"] = ring
    pts["return_type"] = 1
    return pts


def warm_up(config: Config, variant: str, online: bool) -> None:
    """Compile the kernels before receiving (organiser, PRC, filter, KISS-ICP, online detectors)
    on a few synthetic sweeps through throwaway stages, so that the first sweeps are not late."""
    from prc_slam.live.receiver import VelodyneAssembler
    from prc_slam.odometry.compare import OdometryVariants
    from prc_slam.prc.algorithm import warm_up as prc_warm_up

    prc_warm_up()
    assembler = VelodyneAssembler("warm-up")
    assembler.setup("HDL32E")
    scans = [assembler.scan_of(Sweep(i, 0.0, 100.0 + 0.1 * i, synthetic_sweep(turn=0.02 * i))) for i in range(4)]
    detector = None
    if online:
        from prc_slam.online import OnlineDetector

        detector = OnlineDetector()
    stage = OdometryVariants(config.model_copy(deep=True), [variant])
    pipe = LivePipeline(prc=config.prc if stage.needs_prc else None, online=detector, odometry=stage, warn=_silent)
    logging.disable(logging.WARNING)  # the synthetic sweeps' notes are no one's business
    try:
        pipe.run(iter(scans))
    finally:
        logging.disable(logging.NOTSET)


def _silent(_message: str) -> None:
    """Drops a warning."""


class _Signals:
    """SIGINT and SIGTERM set ``stop`` (a second Ctrl-C interrupts at once); restored on exit."""

    def __init__(self, stop: threading.Event) -> None:
        self.stop = stop
        self.saved: dict[int, Any] = {}

    def _handler(self, signum: int, _frame: Any) -> None:
        if self.stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        log.warning(f"{signal.Signals(signum).name}: stopping; flushing the outputs")
        self.stop.set()

    def __enter__(self) -> _Signals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.saved[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self.saved.items():
            signal.signal(sig, handler)


def run_live(
    source: Source,
    config: Config,
    opts: LiveOptions,
    *,
    viewer: Any = None,
    poses_out: Path | None = None,
    filtered_out: Path | None = None,
    labels_out: Path | None = None,
    on_ready: Any = None,
) -> LiveRun:
    """Receive ``source`` and run every sweep through PRC, the filter and the variant's KISS-ICP
    (and the online detectors with ``opts.online``) into the sinks, until stopped.

    ``labels_out``: one ``NNNNNN.label`` per sweep (PRC codes, the offline ``--labels-out``
    format; ``NNNNNN`` the sweep's number in the source). ``on_ready(receiver)`` is called once
    the source listens (its ``port`` is bound)."""
    from prc_slam.jobs.common import Viewer
    from prc_slam.jobs.sinks import ViewerSink
    from prc_slam.odometry.compare import OdometryVariants

    # no next frame made beside the registration: the stage would wait for it (the next sweep,
    # a period away) before giving this one's pose
    config.odometry.overlap = False
    stage = OdometryVariants(config, [opts.variant])
    if opts.warm_up:
        t_warm = time.perf_counter()
        warm_up(config, opts.variant, opts.online)
        log.info(f"live: stages warmed up in {time.perf_counter() - t_warm:.1f} s")
    detector = None
    if opts.online:
        from prc_slam.online import OnlineDetector

        detector = OnlineDetector()
    queue = SweepQueue(opts.queue)
    rx = open_source(source, queue, opts)
    viewer = viewer or Viewer()
    status = Status(rx, queue, opts.status_every, opts.log_every)
    sweeps = LiveSweeps(rx, queue, status, opts)
    sinks: list = []
    written: list[Path] = []
    viz = None
    if viewer.sink is not None:
        viewer.sink.config.variants = [opts.variant]
        viz = BackgroundSink(ViewerSink(viewer.sink))
    poses = None if poses_out is None else PosesFile(poses_out, opts.variant)
    if poses is not None:
        sinks.append(poses)
    mcap = None if filtered_out is None else FilteredMcap(filtered_out, opts.variant)
    if mcap is not None:
        sinks.append(mcap)
    if labels_out is not None and stage.needs_prc:
        from prc_slam.jobs.sinks import LabelFiles

        Path(labels_out).mkdir(parents=True, exist_ok=True)
        sinks.append(LabelFiles(labels_out))
    timed = TimedSinks(sinks, status, opts.variant, viz)
    pipe = LivePipeline(prc=config.prc if stage.needs_prc else None, online=detector, odometry=stage, sinks=[timed])
    result = None
    t0 = time.perf_counter()
    with _Signals(sweeps.stop):
        rx.start()
        log.info(f"live: listening on {source.kind}://{getattr(rx, 'host', '')}:{getattr(rx, 'port', '')}"
                 if source.kind != "file" else f"live: playing {source.path} at its recorded rate")  # fmt: skip
        if on_ready is not None:
            on_ready(rx)
        try:
            result = pipe.run(sweeps)
        except FrameError as exc:
            if "no frame could be read" not in str(exc):
                raise
            log.warning(str(exc))
        except BaseException:
            timed.close(PipelineResult(interrupted=True))  # the pipeline closes its sinks only when it ends
            raise
        finally:
            rx.stop()
            rx.join(timeout=2.0)
            if viewer.sink is not None or viewer.rrd is not None:
                w = viewer.close()
                if w is not None:
                    written.append(w)
    if rx.error is not None:
        raise rx.error
    metrics = live_metrics(rx, queue, status, sweeps, time.perf_counter() - t0)
    if viz is not None:
        metrics["viewer_frames_skipped"] = viz.skipped
    if result is not None and result.odometry is not None:
        try:
            metrics["variants"] = result.odometry.metrics().get("variants", {})
        except Exception as exc:  # the figures above stand without the variant's summary
            log.warning(f"odometry summary not available: {type(exc).__name__}: {exc}")
        metrics.update({k: v for k, v in result.summary().items() if k not in metrics})
    if poses is not None:
        written.append(poses.path)
    if mcap is not None:
        written.append(mcap.path)
    return LiveRun(metrics, written, result)


def live_metrics(rx: Any, queue: SweepQueue, status: Status, sweeps: LiveSweeps, seconds: float) -> dict[str, Any]:
    """The ``live`` metrics (DESIGN.md): frames, drops, losses, latency, rates, per-stage ms."""
    st = rx.stats
    frames = status.frames
    return {
        "frames": frames,
        "dropped_frames": int(queue.dropped),
        "lost_packets": int(st.lost_packets),
        "latency_ms": percentiles_ms(status.latency),
        "rate_hz_in": st.rate_in(),
        "rate_hz_out": rate_out(status.out_times),
        "ms_per_stage": {k: float(np.mean(v)) for k, v in status.stage_ms.items() if v},
        "sweeps_in": int(st.sweeps),
        "packets": int(st.packets),
        "foreign_packets": int(st.foreign_packets),
        "frames_with_lost_packets": int(sum(1 for n in status.lost_per_frame if n)),
        "ended_by": sweeps.ended_by,
        "seconds": seconds,
        "latency_ms_first": [round(x * 1e3, 1) for x in status.latency[:5]],
        "rss_mb": dict(status.rss_mb),
        "warnings": list(st.warnings),
    }
