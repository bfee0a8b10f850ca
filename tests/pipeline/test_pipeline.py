"""The one Pipeline: commands built on it give exactly what the stages give when called directly;
unreadable frames are skipped and counted; interrupts close the sinks as partial; ``compare --online``
logs every stage of every frame into one recording."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.cli import app
from prc_slam.pipeline import (
    ClassifiedFrame,
    FrameError,
    NextFrame,
    Pipeline,
    PipelineFrame,
    PipelineResult,
    ReadAhead,
    classify_frames,
    one_class,
    organize_spans,
)
from prc_slam.prc.config import PRCConfig

runner = CliRunner()


@pytest.fixture(scope="module")
def hdl64(tmp_path_factory) -> Path:
    return write_sequence(Simulator(SimConfig(frames=4, seed=5)), tmp_path_factory.mktemp("pipe") / "hdl64")


@pytest.fixture(scope="module")
def profiler(tmp_path_factory) -> Path:
    cfg = SimConfig(sensor="profiler-urban", frames=3, seed=5)
    return write_sequence(Simulator(cfg), tmp_path_factory.mktemp("pipe") / "profiler")


class Recorder:
    def __init__(self) -> None:
        self.indices: list[int] = []
        self.closed: PipelineResult | None = None

    def frame(self, step: PipelineFrame) -> None:
        self.indices.append(step.index)

    def close(self, result: PipelineResult) -> None:
        self.closed = result


@pytest.mark.parametrize("which", ["hdl64", "profiler"])
def test_classify_labels_equal_the_stage_called_directly(tmp_path, which, request):
    root = request.getfixturevalue(which)
    res = runner.invoke(app, ["classify", str(root), "--preset", "multibeam", "--labels-out", str(tmp_path / "lab")])
    assert res.exit_code == 0, res.output
    direct = classify_frames(iter(open_dataset(root)), PRCConfig.preset("multibeam"))
    n = 0
    for frame in direct:  # a profiler's blocks span frames: the stream, not frame by frame
        written = np.fromfile(tmp_path / "lab" / f"{frame.scan.name}.label", dtype=np.uint32)
        np.testing.assert_array_equal(written & 0xFFFF, frame.point_labels())
        n += 1
    assert n == len(open_dataset(root))


def test_detect_labels_equal_the_detectors_called_directly(tmp_path, hdl64):
    from prc_slam.online import OnlineDetector

    res = runner.invoke(
        app, ["detect", str(hdl64), "--labels-out", str(tmp_path / "lab"), "--json", str(tmp_path / "m.json")]
    )
    assert res.exit_code == 0, res.output
    detector = OnlineDetector()
    for scan in open_dataset(hdl64):
        expected = scan.per_point(detector.process(scan).labels)
        written = np.fromfile(tmp_path / "lab" / f"{scan.name}.label", dtype=np.uint32)
        np.testing.assert_array_equal(written & 0xFFFF, expected)
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["frames"] == 4 and "objects" in m and m["points_per_s"] > 0


def test_unreadable_frames_are_skipped_and_counted(hdl64):
    scans = list(open_dataset(hdl64))
    rec = Recorder()
    warnings: list[str] = []
    result = Pipeline(prc=PRCConfig.preset("multibeam"), sinks=[rec], warn=warnings.append).run(_skipping(scans, {1}))
    assert result.frames == 3 and len(result.skipped) == 1 and "truncated" in result.skipped[0].reason
    assert rec.indices == [0, 1, 2] and rec.closed is result
    assert any("skipped frame 1" in w for w in warnings)
    with pytest.raises(FrameError, match="no frame could be read"):
        Pipeline(prc=PRCConfig.preset("multibeam")).run(_skipping(scans, {0, 1, 2, 3}))


def test_a_truncated_frame_in_a_sequence_is_skipped_by_the_command(tmp_path, hdl64):
    import shutil

    root = tmp_path / "seq"
    shutil.copytree(hdl64, root)
    frame = sorted((root / "frames").glob("*.npz"))[2]
    frame.write_bytes(frame.read_bytes()[:100])
    res = runner.invoke(app, ["classify", str(root), "--json", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    assert "skipped frame 2" in res.output and frame.name in res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["frames"] == 3 and m["skipped_frames"] == 1


class _skipping:
    """An iterator whose ``__next__`` raises :class:`FrameError` for the frames in ``bad`` and goes on."""

    def __init__(self, scans, bad) -> None:
        self.scans, self.bad, self.i = scans, bad, 0

    def __iter__(self):
        return self

    def __next__(self):
        if self.i >= len(self.scans):
            raise StopIteration
        i, self.i = self.i, self.i + 1
        if i in self.bad:
            raise FrameError(f"{self.scans[i].source}: truncated")
        return self.scans[i]


def test_an_interrupt_closes_the_sinks_as_partial(hdl64):
    scans = list(open_dataset(hdl64))

    class Stop(Recorder):
        def frame(self, step):
            super().frame(step)
            if step.index == 1:
                raise KeyboardInterrupt

    rec = Stop()
    with pytest.raises(KeyboardInterrupt):
        Pipeline(prc=PRCConfig.preset("multibeam"), sinks=[rec]).run(iter(scans))
    assert rec.closed is not None and rec.closed.interrupted and rec.closed.frames == 2


def test_compare_online_records_every_stage_of_every_logged_frame(tmp_path, hdl64):
    import rerun.chunk as rc

    rrd = tmp_path / "run.rrd"
    res = runner.invoke(
        app, ["compare", str(hdl64), "--online", "--rrd", str(rrd), "--log-every", "1", "--out", str(tmp_path / "c")]
    )
    assert res.exit_code == 0, res.output
    wanted = {
        "/world/sensor/raw": "Points3D",
        "/world/sensor/filtered": "Points3D",
        "/world/map": "Points3D",
        "/world/trajectory/estimate": "LineStrips3D",
        "/world/detections/cars": "Boxes3D",
        "/world/detections/curbs": "LineStrips3D",
    }
    frames: dict[str, set[int]] = {path: set() for path in wanted}
    for chunk in rc.RrdReader(str(rrd)).store().stream():
        path = chunk.entity_path
        if path not in wanted:
            continue
        rb = chunk.to_record_batch()
        if "frame" in rb.schema.names:
            frames[path].update(rb.column("frame").to_pylist())
    for path, seen in frames.items():
        assert seen == {0, 1, 2, 3}, f"{path}: logged on frames {sorted(seen)}"
    m = json.loads((tmp_path / "c" / "metrics.json").read_text())
    assert m["online"]["frames"] == 4 and "per_class" in m["online"]


def test_next_frame_made_beside_the_caller_comes_back_in_order_with_its_errors():
    made: list[int] = []

    def frames():
        for i in range(3):
            made.append(i)
            yield i
        raise FrameError("seq/000003.bin: truncated")

    ahead = NextFrame(frames())
    assert ahead.wait() == 0.0  # nothing begun
    ahead.start()
    ahead.start()  # once begun, not again
    assert ahead.wait() >= 0.0 and made == [0]
    assert ahead.take() == 0
    assert ahead.take() == 1  # made on demand
    ahead.start()
    assert ahead.take() == 2
    ahead.start()
    with pytest.raises(FrameError, match=r"000003\.bin: truncated"):  # raised again in this thread
        ahead.take()
    assert ahead.take() is None and ahead.take() is None  # the end, for good


class _Source:
    """Scans ``0..n-1`` (stand-ins) from ``next()``; the indices in ``bad`` raise FrameError in their
    turn and the iteration goes on (as ``jobs.common.frames_of``). Records what was read when."""

    def __init__(self, n: int, bad: set[int]) -> None:
        self.n, self.bad, self.i, self.reads = n, bad, 0, []

    def __iter__(self):
        return self

    def __next__(self):
        if self.i >= self.n:
            raise StopIteration
        i, self.i = self.i, self.i + 1
        self.reads.append(i)
        if i in self.bad:
            raise FrameError(f"seq/{i:06d}.bin: truncated")
        return SimpleNamespace(i=i, meta={})


def _drain(it, fills) -> list:
    """Everything ``it`` gives (values, and errors by message), calling ``it.fill()`` before the
    k-th ``next()`` when ``fills[k]``."""
    out = []
    for k in range(10_000):
        if k < len(fills) and fills[k]:
            it.fill()
        try:
            out.append(next(it))
        except FrameError as exc:
            out.append(str(exc))
        except StopIteration:
            return out
    raise AssertionError("did not end")


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(0, 8),
    bad=st.sets(st.integers(0, 7), max_size=4),
    fills=st.lists(st.booleans(), max_size=20),
)
def test_read_ahead_gives_the_source_in_order_whenever_it_reads(n, bad, fills):
    """Whatever the calls of ``fill()``, the scans and the unreadable frames' errors come in the
    source's order, each once, and nothing is read more than one scan ahead."""
    plain = _drain(_Source(n, bad), [])
    source = _Source(n, bad)
    ahead = ReadAhead(source)
    got = _drain(ahead, fills)
    assert got == plain
    assert source.reads == list(range(n))


def test_read_ahead_reads_after_the_frame_is_made_and_charges_its_organising():
    """NextFrame makes a frame, then reads (and organises) the one after: ``charged`` holds that
    frame's PRC interval and the read-ahead scan's organising interval (not an earlier one's)."""
    events: list[str] = []
    organised: dict[int, tuple[float, float]] = {}

    class Scan_:
        def __init__(self, i: int) -> None:
            t = time.perf_counter()
            self.i, self.meta = i, {"organize_span": (t - 1e-3, t)}
            organised[i] = self.meta["organize_span"]

    def scans():
        for i in range(3):
            events.append(f"read {i}")
            yield Scan_(i)

    def classified(read):
        for s in read:
            events.append(f"prc {s.i}")
            t = time.perf_counter()
            yield ClassifiedFrame(s, None, 0.0, spans=(*organize_spans(s), (t - 2e-3, t)))

    read = ReadAhead(scans())
    made = NextFrame(classified(read), read)
    assert made.take().scan.i == 0 and events == ["read 0", "prc 0", "read 1"]
    # frame 0 was read and organised in this call too
    assert len(made.charged) == 3 and made.charged[0] == organised[0] and made.charged[2] == organised[1]
    made.start()
    assert made.take().scan.i == 1 and events[-2:] == ["prc 1", "read 2"]
    assert len(made.charged) == 2 and made.charged[1] == organised[2]  # frame 1's organising was charged before
    assert made.take().scan.i == 2 and len(made.charged) == 1  # nothing left to read
    assert made.take() is None and made.charged == ()


def test_an_interrupt_while_reading_ahead_comes_after_the_frame_made():
    """Ctrl-C while the next sweep is read (after this one's PRC): this frame is still given (its
    sinks run), the interrupt comes at the next take, and no thread is started meanwhile."""

    def scans():
        yield SimpleNamespace(i=0, meta={})
        raise KeyboardInterrupt

    read = ReadAhead(scans())
    made = NextFrame((ClassifiedFrame(s, None, 0.0) for s in read), read)
    assert made.take().scan.i == 0
    made.start()  # pending interrupt: nothing begun
    assert made.wait() == 0.0
    with pytest.raises(KeyboardInterrupt):
        made.take()


def test_one_class_by_hand():
    ranges = np.ones((10, 200), np.float32)
    ranges[0, :100] = 0.0  # no returns: not counted
    labels = np.full((10, 200), L.NOISE, np.uint8)
    labels[0, :100] = L.GROUND
    assert one_class(labels, ranges) == ("noise", 100.0)
    labels[1, :19] = L.GROUND  # 19 of 1900 returns: 99.0 % noise
    assert one_class(labels, ranges)[0] == "noise"
    labels[1, 19] = L.GROUND  # 20 of 1900: under 99 %
    assert one_class(labels, ranges) is None
    assert one_class(labels[:2], ranges[:2]) is None  # too few returns to tell


def test_a_run_with_one_class_everywhere_is_warned(hdl64):
    """Sweeps in millimetres: the paper's metric thresholds call every return noise."""
    scans = [replace(s, ranges=s.ranges * 1000.0) for s in open_dataset(hdl64)]
    warnings: list[str] = []
    result = Pipeline(prc=PRCConfig.preset("urban"), warn=warnings.append).run(iter(scans))
    assert result.frames_one_class == len(scans) and result.summary()["frames_one_class"] == len(scans)
    assert len([w for w in warnings if "of the returns in one class (noise)" in w]) == 1  # once per run
    plain = Pipeline(prc=PRCConfig.preset("urban")).run(open_dataset(hdl64))
    assert plain.frames_one_class == 0 and "frames_one_class" not in plain.summary()
