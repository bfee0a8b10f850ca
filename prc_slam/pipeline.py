"""The one per-frame loop: source → organise → PRC → online detectors → filter → odometry → sinks.

:class:`Pipeline` composes the stages a run asks for and hands every frame, as one
:class:`PipelineFrame`, to each sink in turn (scorers, label files, LAS, trajectories, the
filtered stream, Rerun). Every command of the CLI is a configuration of it; users who bring their
own loop take :class:`prc_slam.preprocess.Preprocessor` or :class:`prc_slam.preprocess.PRCKissICP`
instead.

Frames that cannot be read are skipped, counted and reported (``PipelineResult.skipped``), never
silently dropped; a run in which no frame could be read is an error naming the first problem.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from prc_slam import labels as L
from prc_slam.prc import PRCStream, prc_block
from prc_slam.prc.config import AutoPreset, PRCConfig
from prc_slam.prc.ground import GroundState, upside_down
from prc_slam.scan import Scan, ScanError, SpinningSensor
from prc_slam.util.frame_process import ForkedNextFrame, FrameProcessEnded, can_fork

log = logging.getLogger("prc_slam.pipeline")


class FrameError(ValueError):
    """A frame of the input could not be read; the message names the file and the problem."""


@dataclass
class ClassifiedFrame:
    """One input frame with its PRC labels per slot and the PRC compute time spent on it
    (``seconds``: the classifier's, plus the organiser's when the reader had to organise the sweep).

    ``labels`` is None when the run has no PRC stage. ``one_sided`` marks noise slots that meet
    one of the two support conditions of eq. (4) (thin poles, edges), as opposed to isolated
    returns. ``spans`` are the ``time.perf_counter()`` intervals of the work in ``seconds``
    (organising, classifying) and ``filter_seconds``, for the credit of work done beside the
    registration. ``filtered`` is the label-driven filter's choice of points
    (:class:`prc_slam.filtering.FilterResult`, input order) when the odometry stage made it with
    the frame (:meth:`OdometryStage.prepare`), in ``filter_seconds``.
    """

    scan: Scan
    labels: np.ndarray | None
    seconds: float
    one_sided: np.ndarray | None = None
    ground_error: str | None = None
    spans: tuple[tuple[float, float], ...] = ()
    filtered: Any = None
    filter_seconds: float = 0.0

    def point_labels(self) -> np.ndarray:
        """Labels per input point, in input order."""
        if self.labels is None:
            raise ValueError(f"{self.scan.source}: this run has no PRC labels")
        return self.scan.per_point(self.labels)

    def point_one_sided(self) -> np.ndarray:
        """``one_sided`` per input point (all False when unknown)."""
        if self.one_sided is None:
            return np.zeros(self.scan.n_points, dtype=bool)
        return self.scan.per_point(self.one_sided)


def unclassified(scans: Iterable[Scan]) -> Iterator[ClassifiedFrame]:
    """The scans as frames of a run without a PRC stage (no labels)."""
    for scan in scans:
        yield ClassifiedFrame(scan, None, 0.0)


def classify_frames(scans: Iterable[Scan], config: PRCConfig | AutoPreset) -> Iterator[ClassifiedFrame]:
    """Classify a sequence of scans with PRC, yielding each frame once all its slots are labelled.
    An :class:`AutoPreset` is resolved on the first scan (and the choice said on the log).

    A spinning sensor's sweep is one block; the column ground's state (its ground plane) is
    carried from sweep to sweep. A continuous sensor's (profiler's) scan lines form one stream cut
    into blocks of ``config.k`` lines regardless of frame boundaries, so the labels do not depend
    on how the recording was split into frames.
    """
    stream: PRCStream | None = None
    ground_state = GroundState()
    pending: list[tuple[Scan, int, np.ndarray, np.ndarray]] = []  # scan, first stream row, labels, one_sided
    next_row = 0
    spent = 0.0  # PRC time not yet attributed to a yielded frame
    spent_spans: list[tuple[float, float]] = []  # and its intervals
    for scan in scans:
        if isinstance(config, AutoPreset):
            auto, config = config, config.resolve(scan.sensor)
            log.info(f"PRC preset {auto.why} (--preset paper or multibeam to choose)")
        if not scan.sensor.continuous_rows:
            wrap = True if config.wrap_columns is None else config.wrap_columns
            t0 = time.perf_counter()
            res = prc_block(scan.ranges, config, sensor=scan.sensor, wrap=wrap, ground_state=ground_state)
            t1 = time.perf_counter()
            # organising an unorganised sweep (KITTI bins, PCD, bags) is PRC's cost too
            seconds = t1 - t0 + float(scan.meta.get("organize_seconds", 0.0))
            spans = (*organize_spans(scan), (t0, t1))
            ground_error = getattr(res, "ground_error", None)
            yield ClassifiedFrame(scan, res.labels, seconds, res.one_sided, ground_error, spans)
            continue
        if stream is None:
            stream = PRCStream(config, scan.sensor)
        elif scan.sensor.cols != stream.sensor.cols:
            raise ScanError(
                f"{scan.source}: {scan.sensor.cols} points per scan line, the stream has {stream.sensor.cols}"
            )
        pending.append((scan, next_row, np.zeros(scan.shape, dtype=np.uint8), np.zeros(scan.shape, dtype=bool)))
        next_row += scan.shape[0]
        t0 = time.perf_counter()
        blocks = stream.push(scan.ranges)
        t1 = time.perf_counter()
        spent += t1 - t0
        spent_spans.append((t0, t1))
        for done, labels, one_sided in _complete(pending, blocks):
            yield ClassifiedFrame(done, labels, spent, one_sided, spans=tuple(spent_spans))
            spent, spent_spans = 0.0, []
    if stream is not None:
        t0 = time.perf_counter()
        blocks = stream.flush()
        t1 = time.perf_counter()
        spent += t1 - t0
        spent_spans.append((t0, t1))
        for done, labels, one_sided in _complete(pending, blocks):
            yield ClassifiedFrame(done, labels, spent, one_sided, spans=tuple(spent_spans))
            spent, spent_spans = 0.0, []
        if pending:
            raise RuntimeError("PRC stream flushed with frames still unlabelled")


def organize_spans(scan: Scan) -> tuple[tuple[float, float], ...]:
    """The organiser's ``time.perf_counter()`` interval for ``scan`` (none for organised input)."""
    span = scan.meta.get("organize_span")
    return () if span is None else ((float(span[0]), float(span[1])),)


def _complete(pending: list, blocks: list) -> list[tuple[Scan, np.ndarray, np.ndarray]]:
    """Copy block results into the pending frames; pop and return the frames now complete."""
    for block in blocks:
        b0, b1 = block.row0, block.row0 + block.labels.shape[0]
        for _scan, f0, labels, one_sided in pending:
            lo, hi = max(b0, f0), min(b1, f0 + labels.shape[0])
            if lo < hi:
                labels[lo - f0 : hi - f0] = block.labels[lo - b0 : hi - b0]
                one_sided[lo - f0 : hi - f0] = block.one_sided[lo - b0 : hi - b0]
    if not blocks:
        return []
    done_rows = blocks[-1].row0 + blocks[-1].labels.shape[0]
    out = []
    while pending and pending[0][1] + pending[0][2].shape[0] <= done_rows:
        scan, _, labels, one_sided = pending.pop(0)
        out.append((scan, labels, one_sided))
    return out


#: a frame with this share of its returns in one PRC class is reported (no real sweep is all
#: ground or all noise; a wrong sensor model or unit is)
ONE_CLASS_SHARE = 0.99


def one_class(labels: np.ndarray, ranges: np.ndarray, min_returns: int = 1000) -> tuple[str, float] | None:
    """``(class name, percent)`` when one class holds :data:`ONE_CLASS_SHARE` or more of a frame's
    returns (slots with a range; frames of at least ``min_returns``), else None."""
    codes = np.asarray(labels)[np.asarray(ranges) > 0]
    if len(codes) < min_returns:
        return None
    counts = np.bincount(codes.ravel(), minlength=256)
    top = int(np.argmax(counts))
    if counts[top] < ONE_CLASS_SHARE * len(codes):
        return None
    return L.names([top])[0], 100.0 * counts[top] / len(codes)


#: A frame with this share of its returns called noise or more is warned (rain, snow and dust
#: can do that; so can a range image that does not fit the sensor: isolated slots everywhere).
NOISE_WARN_SHARE = 0.25


def noise_share(labels: np.ndarray, ranges: np.ndarray, min_returns: int = 1000) -> float | None:
    """The share of a frame's returns (slots with a range) labelled noise, for frames of at least
    ``min_returns`` returns (else None)."""
    ret = np.asarray(ranges) > 0
    n = int(np.count_nonzero(ret))
    if n < min_returns:
        return None
    return int(np.count_nonzero(np.asarray(labels)[ret] == L.NOISE)) / n


def mostly_noise_message(scan: Scan, share: float) -> str:
    """The warning for a frame of which PRC called ``share`` (>= :data:`NOISE_WARN_SHARE`) noise."""
    rows, cols = scan.ranges.shape
    fill = np.count_nonzero(scan.ranges > 0) / max(scan.ranges.size, 1)
    return (
        f"{scan.source}: PRC called {share:.1%} of the range image's returns noise (isolated): rain, snow or dust "
        "can do that; so can a sensor whose points do not lie on the rings of a spinning one (mirror-scanning, "
        f"solid-state) or a range image that does not fit it ({rows} x {cols} slots, {fill:.1%} holding a return: "
        "check --rows / --cols)"
    )


_END = object()


class ReadAhead(Iterator[Scan]):
    """The scans of ``scans``, each read one call of :meth:`fill` before it is asked for.

    :class:`NextFrame` calls :meth:`fill` once it has made a frame, so that the next sweep is read
    (and, for an unorganised input, organised) after the current one's PRC instead of before it:
    the PRC then falls inside the registration it is made beside, and reading, which is no
    variant's cost, after it. A scan that could not be read raises its error from ``next()`` in
    its turn (the iteration goes on, as the source's own); without :meth:`fill` every scan is read
    when asked for.
    """

    def __init__(self, scans: Iterable[Scan]) -> None:
        self._scans = iter(scans)
        self._held: list[tuple[Scan | None, Exception | None]] = []
        self._ended = False
        #: the organiser's interval of the scan read by the last :meth:`fill` (none: organised input)
        self.spans: tuple[tuple[float, float], ...] = ()

    def _read(self) -> tuple[Scan | None, Exception | None]:
        try:
            return next(self._scans), None
        except StopIteration:
            self._ended = True
            return None, None
        except Exception as exc:  # raised again by __next__, in its turn
            return None, exc

    def fill(self) -> None:
        """Read the next scan now (nothing when one is held or the input has ended)."""
        self.spans = ()
        if self._held or self._ended:
            return
        scan, error = self._read()
        if scan is not None or error is not None:
            self._held.append((scan, error))
            if scan is not None:
                self.spans = organize_spans(scan)

    def __next__(self) -> Scan:
        scan, error = self._held.pop() if self._held else self._read()
        if error is not None:
            raise error
        if scan is None:
            raise StopIteration
        return scan


class NextFrame:
    """The next frame of a run: made on demand (:meth:`take`), or on a background thread beside
    the caller's work on the current frame (:meth:`start`, then :meth:`wait`).

    The odometry stage starts it once the variants that do not need PRC have registered the
    current frame, so that classifying the next sweep (and reading and organising the one after,
    with a :class:`ReadAhead`) shares the cores with the current sweep's filter and registration
    (KISS-ICP holds the GIL while it registers; the organiser's and PRC's numba kernels release
    it). ``charged`` lists the intervals of the organising and PRC done while making it, wherever
    they belong. An error raised while making the frame is raised again by :meth:`take`, in the
    caller's thread.
    """

    def __init__(self, frames: Iterator[ClassifiedFrame], ahead: ReadAhead | None = None) -> None:
        self._frames = frames
        self._ahead = ahead
        self._thread: threading.Thread | None = None
        self._item: Any = None
        self._error: BaseException | None = None
        self.seconds = 0.0  # wall time of making the last frame (not of reading ahead)
        self.charged: tuple[tuple[float, float], ...] = ()
        self._later: BaseException | None = None  # an interrupt while reading ahead, after the frame made

    def _advance(self) -> None:
        t0 = time.perf_counter()
        self.charged = ()
        try:
            self._item = next(self._frames, _END)
        except BaseException as exc:  # raised again by take(), in the caller's thread
            self._error = exc
        self.seconds = time.perf_counter() - t0
        made = self._item.spans if isinstance(self._item, ClassifiedFrame) else ()
        if self._ahead is not None and self._error is None:
            try:
                self._ahead.fill()  # (a frame that cannot be read raises in its turn, not here)
            except BaseException as exc:  # e.g. Ctrl-C: the frame made is still given, then this
                self._later = exc
            made = (*made, *self._ahead.spans)
        self.charged = tuple(s for s in made if s[1] > t0)

    def start(self) -> None:
        """Begin making the next frame on a background thread (nothing when already begun, or when
        an interrupt is pending)."""
        if self._thread is None and self._later is None:
            self._thread = threading.Thread(target=self._advance, name="prc-slam-next-frame", daemon=True)
            self._thread.start()

    def wait(self) -> float:
        """Wait until the frame begun by :meth:`start` is made; its wall time (s), 0 if not begun."""
        if self._thread is None:
            return 0.0
        self._thread.join()
        return self.seconds

    def close(self) -> None:
        """Nothing to end (:class:`~prc_slam.util.frame_process.ForkedNextFrame` ends its process)."""

    def take(self) -> ClassifiedFrame | None:
        """The next frame (None after the last), made now unless :meth:`start` began it."""
        if self._later is not None and self._thread is None:
            later, self._later = self._later, None
            raise later
        if self._thread is None:
            self._advance()
        else:
            self._thread.join()
            self._thread = None
        item, error = self._item, self._error
        self._item = self._error = None
        if error is not None:
            raise error
        return None if item is _END else item


@dataclass
class PipelineFrame:
    """Everything the stages produced for one input frame, as the sinks see it.

    Attributes
    ----------
    index : int
        Position of the frame in the run (0-based, skipped frames not counted).
    frame : ClassifiedFrame
        The scan and its PRC labels per slot (``labels`` None without a PRC stage).
    online : object or None
        The online detectors' result (:class:`prc_slam.online.OnlineResult`), when run.
    odometry : object or None
        The odometry variants' record of this frame (``prc_slam.odometry.compare.FrameRecord``).
    """

    index: int
    frame: ClassifiedFrame
    online: Any = None
    odometry: Any = None

    @property
    def scan(self) -> Scan:
        return self.frame.scan


@dataclass
class Skip:
    """A frame left out of the run, and why."""

    index: int
    source: str
    reason: str


@dataclass
class PipelineResult:
    """What a run produced, for the sinks' ``close`` and the caller.

    ``prc_seconds`` and ``online_seconds`` are the stages' own compute times (what
    ``points_per_s`` divides by); ``wall_seconds`` is the whole loop.
    """

    frames: int = 0
    points: int = 0
    nonfinite_points: int = 0
    empty_frames: int = 0
    frames_without_ground: int = 0
    frames_one_class: int = 0  # frames with ONE_CLASS_SHARE of their returns or more in one class
    frames_mostly_noise: int = 0  # frames with NOISE_WARN_SHARE of their returns or more called noise
    prc_seconds: float = 0.0
    online_seconds: float = 0.0
    online_seconds_first: float = 0.0
    online_points_first: int = 0
    wall_seconds: float = 0.0
    skipped: list[Skip] = field(default_factory=list)
    odometry: Any = None
    organize: dict[str, Any] = field(default_factory=dict)
    interrupted: bool = False
    next_frame: str | None = None  # where the next frame was made beside the registration: process, thread
    ended_early: str | None = None  # why the run stopped before the input's end (its frame process ended)

    def summary(self) -> dict[str, Any]:
        """Counts for the metrics JSON: frames, points, skipped frames and points, organiser warnings."""
        out: dict[str, Any] = {
            "frames": self.frames,
            "points": self.points,
            "skipped_frames": len(self.skipped),
            "skipped_points": self.nonfinite_points,
            "empty_frames": self.empty_frames,
        }
        if self.frames_without_ground:
            out["frames_without_ground"] = self.frames_without_ground
        if self.frames_one_class:
            out["frames_one_class"] = self.frames_one_class
        if self.frames_mostly_noise:
            out["frames_mostly_noise"] = self.frames_mostly_noise
        if self.skipped:
            out["skips"] = [{"index": s.index, "source": s.source, "reason": s.reason} for s in self.skipped]
        if self.organize:
            out["organize"] = self.organize
        if self.interrupted:
            out["interrupted"] = True
        if self.next_frame:
            out["next_frame_made_in"] = self.next_frame
        if self.ended_early:
            out["ended_early"] = self.ended_early
        return out


class Sink(Protocol):
    """Receives every frame of a run, then the result. Sinks must not modify what they get."""

    def frame(self, step: PipelineFrame) -> None: ...

    def close(self, result: PipelineResult) -> None: ...


class OdometryStage(Protocol):
    """The odometry variants as one stage (``prc_slam.odometry.compare.OdometryVariants``).

    ``prepare`` does the per-frame work that needs only the frame (the label-driven filter), as
    the frame is made: beside the registration of the frame before when the next frame is made
    there (``odometry.overlap``)."""

    def prepare(self, frame: ClassifiedFrame) -> ClassifiedFrame: ...

    def step(self, index: int, frame: ClassifiedFrame, ahead: NextFrame | None = None) -> Any: ...

    def result(self) -> Any: ...


class Pipeline:
    """One per-frame loop over the stages a run needs, feeding its sinks.

    Parameters
    ----------
    prc : PRCConfig, AutoPreset or None
        Run PRC with this configuration, or the one an :class:`AutoPreset` chooses on the first
        scan (None: no PRC stage; frames carry no labels).
    online : object or None
        An :class:`prc_slam.online.OnlineDetector` to run on every scan.
    odometry : OdometryStage or None
        The odometry variants (each filters with the PRC labels as its policy says, then registers).
        The stage may have the next frame made beside its registration of this one (:class:`NextFrame`).
    sinks : sequence of Sink
        Called in order for every frame and once at the end.
    on_frame : callable, optional
        Called after the sinks for every frame (progress bars).
    warn : callable(str), optional
        Receives every warning (organiser, skipped frames); defaults to the module logger (the
        organiser's warnings are then only in its own log, not repeated).

    Examples
    --------
    >>> from prc_slam import Pipeline, PRCConfig
    >>> from prc_slam.evaluation.scoring import PRCScorer
    >>> scorer = PRCScorer()
    >>> result = Pipeline(prc=PRCConfig.preset("multibeam"), sinks=[scorer]).run(scans)  # doctest: +SKIP
    >>> scorer.metrics(result)["per_class"]["ground"]["recall"]  # doctest: +SKIP
    """

    def __init__(
        self,
        *,
        prc: PRCConfig | AutoPreset | None = None,
        online: Any = None,
        odometry: OdometryStage | None = None,
        sinks: Sequence[Sink] = (),
        on_frame: Callable[[PipelineFrame], None] | None = None,
        warn: Callable[[str], None] | None = None,
    ) -> None:
        self.prc = prc
        self.online = online
        self.odometry = odometry
        self.sinks = list(sinks)
        self.on_frame = on_frame
        self.warn = warn or log.warning
        self.warn_organizer = warn is not None

    def _readable(self, scans: Iterable[Scan], result: PipelineResult) -> Iterator[Scan]:
        """The scans that could be read; the others are skipped with a warning and counted."""
        it = iter(scans)
        index = 0
        while True:
            try:
                scan = next(it)
            except StopIteration:
                return
            except (FrameError, ScanError) as exc:
                result.skipped.append(Skip(index, getattr(exc, "source", ""), str(exc)))
                self.warn(f"skipped frame {index}: {exc}")
                index += 1
                continue
            index += 1
            org = scan.meta.get("organize")
            if org:
                self._merge_organize(result, org, scan.source)
            nonfinite = (org or {}).get("nonfinite_points", 0) or scan.meta.get("nonfinite_points", 0)
            result.nonfinite_points += int(nonfinite)
            yield scan

    def _merge_organize(self, result: PipelineResult, org: dict[str, Any], source: str) -> None:
        agg = result.organize
        agg["method"] = org.get("method")
        agg["frames"] = agg.get("frames", 0) + 1
        agg["rings"] = org.get("rings")
        agg["collisions_pct_max"] = max(agg.get("collisions_pct_max", 0.0), float(org.get("collisions_pct", 0.0)))
        warnings = org.get("warnings") or []
        if warnings:
            agg["warnings"] = agg.get("warnings", 0) + len(warnings)
            if self.warn_organizer:  # else the organiser has logged them already
                for w in warnings:
                    self.warn(w if source in w else f"{source}: {w}")

    def _classified(self, scans: Iterable[Scan]) -> Iterator[ClassifiedFrame]:
        frames = classify_frames(scans, self.prc) if self.prc is not None else unclassified(scans)
        prepare = getattr(self.odometry, "prepare", None)
        yield from frames if prepare is None else map(prepare, frames)

    def run(self, scans: Iterable[Scan]) -> PipelineResult:
        """Run every stage over ``scans`` and return what was produced.

        A ``KeyboardInterrupt`` stops the loop after the current frame's sinks: the sinks are
        closed with ``result.interrupted = True`` (so they can mark their outputs partial) and the
        interrupt is raised again.
        """
        result = PipelineResult()
        t_start = time.perf_counter()
        frames = self._next_frames(ReadAhead(scans), result)
        index = -1
        try:
            while (frame := self._take(frames, result, index + 1)) is not None:
                index += 1
                scan = frame.scan
                n = scan.n_points
                result.frames += 1
                result.points += n
                result.prc_seconds += frame.seconds
                if n == 0:
                    result.empty_frames += 1
                    self.warn(f"{scan.source}: empty sweep (no returns)")
                elif frame.ground_error is not None:
                    result.frames_without_ground += 1
                    self.warn(f"{scan.source}: PRC found no ground model: {frame.ground_error}")
                if index == 0 and frame.labels is not None and isinstance(scan.sensor, SpinningSensor) and n:
                    turned = upside_down(scan.sensor.to_xyz(scan.ranges), scan.ranges > 0, scan.sensor.altitude)
                    if turned is not None:
                        self.warn(f"{scan.source}: {turned}")
                if frame.labels is not None and (one := one_class(frame.labels, scan.ranges)) is not None:
                    result.frames_one_class += 1
                    if result.frames_one_class == 1:  # once per run; the count is in the summary
                        self.warn(
                            f"{scan.source}: PRC put {one[1]:.1f}% of the returns in one class ({one[0]}): the "
                            "sensor model or the units are likely wrong for this input"
                        )
                elif frame.labels is not None and (share := noise_share(frame.labels, scan.ranges)) is not None:
                    if share >= NOISE_WARN_SHARE:
                        result.frames_mostly_noise += 1
                        if result.frames_mostly_noise == 1:  # once per run; the count is in the summary
                            self.warn(mostly_noise_message(scan, share))
                step = PipelineFrame(index, frame)
                if self.online is not None:
                    step.online = self.online.process(scan)
                    result.online_seconds += step.online.seconds
                    if index == 0:  # the first frame also loads the compiled kernels
                        result.online_seconds_first = step.online.seconds
                        result.online_points_first = n
                if self.odometry is not None:
                    step.odometry = self.odometry.step(index, frame, frames)
                for sink in self.sinks:
                    sink.frame(step)
                if self.on_frame is not None:
                    self.on_frame(step)
        except KeyboardInterrupt:
            result.interrupted = True
            frames.wait()  # the next frame's thread writes into result (skips, organiser)
            frames.close()
            self._finish(result, t_start)
            raise
        except BaseException:
            frames.wait()
            frames.close()
            raise
        frames.close()
        self._finish(result, t_start)
        if result.frames == 0 and result.skipped:
            raise FrameError(f"no frame could be read; first problem: {result.skipped[0].reason}")
        return result

    def _take(self, frames: Any, result: PipelineResult, index: int) -> ClassifiedFrame | None:
        """The next frame; None at the end, and when the process making the frames has ended: the
        run stops there, said and recorded (``ended_early``), and every output covers the frames
        before (as at the end of the input)."""
        try:
            return frames.take()
        except FrameProcessEnded as exc:
            result.ended_early = f"{exc}; the run stopped before frame {index}"
            self.warn(f"{result.ended_early}: the outputs cover frames 0 to {index - 1}")
            return None

    def _next_frames(self, ahead: ReadAhead, result: PipelineResult) -> Any:
        """The frames of ``ahead``, read, organised and classified: on a second thread when the
        odometry stage makes the next frame beside its registration, in a forked process when
        its ``odometry.overlap_process`` says so and a fork is safe here
        (:mod:`prc_slam.util.frame_process`: KISS-ICP holds the GIL while it registers)."""

        def make() -> NextFrame:
            return NextFrame(self._classified(self._readable(ahead, result)), ahead)

        cfg = getattr(getattr(self.odometry, "config", None), "odometry", None)
        if cfg is None or not cfg.overlap:
            return make()
        result.next_frame = "thread"
        if not cfg.overlap_process:
            return make()
        ok, why = can_fork()
        if not ok:
            log.info("the next frame is made on a thread beside the registration: %s", why)
            return make()
        result.next_frame = "process"
        sent: list[str] = []

        def make_in_child() -> NextFrame:
            self.warn = sent.append  # passed on to the caller's warn with each frame
            return make()

        def absorb(state: tuple) -> None:  # what the source wrote, in the child, as it read
            result.skipped, result.organize, result.nonfinite_points = state

        def state() -> tuple:
            return result.skipped, result.organize, result.nonfinite_points

        return ForkedNextFrame(make_in_child, state, absorb, sent, self.warn)

    def _finish(self, result: PipelineResult, t_start: float) -> None:
        result.wall_seconds = time.perf_counter() - t_start
        if self.odometry is not None:
            result.odometry = self.odometry.result()
        for sink in self.sinks:
            sink.close(result)
