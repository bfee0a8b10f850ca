"""The live run's sinks: the timed file sinks (poses, labels, filtered MCAP) with the latency
taken after them, and the viewer's logging on its own thread."""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prc_slam.pipeline import PipelineFrame, PipelineResult

if TYPE_CHECKING:
    from prc_slam.live.run import Status

log = logging.getLogger("prc_slam")
#: resident memory is recorded after every this many sweeps of the source (metrics ``rss_mb``)
RSS_EVERY = 50


def rss_mb() -> float:
    """This process's resident memory (MB; 0 where /proc is not)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


class TimedSinks:
    """The run's file sinks as one, timed (the ``sinks`` stage), then the frame's latency; then the
    viewer's sink, on its own thread (:class:`BackgroundSink`)."""

    def __init__(self, sinks: list, status: Status, variant: str, viz: BackgroundSink | None = None) -> None:
        self.sinks, self.status, self.variant, self.viz = sinks, status, variant, viz

    def frame(self, step: PipelineFrame) -> None:
        t0 = time.perf_counter()
        for sink in self.sinks:
            sink.frame(step)
        now = time.perf_counter()
        st = self.status
        st.stage_ms["sinks"].append((now - t0) * 1e3)
        received = step.scan.meta.get("live_received")
        if received is not None:
            st.latency.append(now - received)
        st.frames += 1
        index = int(step.scan.meta.get("live_index", st.frames - 1))  # the sweep's number in the source
        if index + 1 >= st.next_rss:
            st.rss_mb[str(index + 1)] = rss_mb()
            st.next_rss = (index + 1) // RSS_EVERY * RSS_EVERY + RSS_EVERY
        if not step.scan.meta.get("live_flushed"):
            st.out_times.append(now)
        st.lost_per_frame.append(int(step.scan.meta.get("live_lost_packets", 0)))
        organize = float(step.scan.meta.get("organize_seconds", 0.0)) * 1e3
        st.stage_ms["organize"].append(organize)
        st.stage_ms["prc"].append(step.frame.seconds * 1e3 - organize)
        if step.online is not None:
            st.stage_ms["online"].append(step.online.seconds * 1e3)
        if step.odometry is not None and self.variant in step.odometry.runs:
            ms = step.odometry.ms(self.variant)
            for k in ("filter", "icp"):
                if k in ms:
                    st.stage_ms[k].append(ms[k])
        if self.viz is not None:  # after the latency: the viewer shows the frame when its thread has logged it
            self.viz.frame(step)
        st.tick()

    def close(self, result: PipelineResult) -> None:
        for sink in self.sinks:
            sink.close(result)
        if self.viz is not None:
            self.viz.close(result)


class BackgroundSink:
    """A sink run on its own thread (the Rerun logging): the live loop hands it each frame and
    goes on; when it is still busy with ``maxsize`` frames, the frame is not logged (counted in
    ``skipped``), so that watching never delays the poses and labels. :meth:`close` waits for it
    to log what it holds, then closes the sink."""

    def __init__(self, sink: Any, maxsize: int = 2) -> None:
        import queue

        self.sink = sink
        self.skipped = 0
        self._q: queue.Queue = queue.Queue(maxsize)
        self._full = queue.Full
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._work, name="prc-slam-viewer", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while (step := self._q.get()) is not None:
            try:
                self.sink.frame(step)
            except Exception as exc:  # the run goes on; said once at the end
                self.error = self.error or exc

    def frame(self, step: PipelineFrame) -> None:
        try:
            self._q.put_nowait(step)
        except self._full:
            self.skipped += 1

    def close(self, result: PipelineResult) -> None:
        self._q.put(None)
        self._thread.join(timeout=60)
        if self.error is not None:
            log.warning(f"Rerun logging failed: {type(self.error).__name__}: {self.error}")
        self.sink.close(result)


class PosesFile:
    """The poses of the run's variant as TUM lines (``t x y z qx qy qz qw``), one per frame,
    flushed as they come: the file is valid whenever the run stops."""

    def __init__(self, path: Path, variant: str) -> None:
        self.path, self.variant = Path(path), variant
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = self.path.open("w")
        self.lines = 0

    def frame(self, step: PipelineFrame) -> None:
        from scipy.spatial.transform import Rotation

        rec = step.odometry
        if rec is None or self.variant not in rec.poses:
            return
        pose = np.asarray(rec.poses[self.variant])
        t = step.scan.meta.get("frame_time")
        if t is None:
            pt = step.scan.point_times()
            t = float(np.min(pt)) if pt is not None and len(pt) else float(step.index)
        q = Rotation.from_matrix(pose[:3, :3]).as_quat()
        x, y, z = pose[:3, 3]
        self._f.write(f"{float(t):.6f} {x:.9f} {y:.9f} {z:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")
        self._f.flush()
        self.lines += 1

    def close(self, result: PipelineResult) -> None:
        self._f.close()


class FilteredMcap:
    """The filtered stream (the points the variant registers, with their PRC label) as
    ``sensor_msgs/PointCloud2`` messages in an MCAP file, one per sweep.

    The messages go to a rosbag2 MCAP written as the run goes; :meth:`close` moves it to ``path``
    (on Ctrl-C / SIGTERM too, since the run ends normally then)."""

    def __init__(self, path: Path, variant: str, topic: str = "/points_filtered") -> None:
        from data_tools.formats.stream_out import RosCloudWriter

        self.path, self.variant = Path(path), variant
        self.writer = RosCloudWriter(self.path, "mcap", topic, overwrite=True)
        self.frames = 0

    def frame(self, step: PipelineFrame) -> None:
        from data_tools.formats.rosbag import DATATYPE_CODES, CloudMessage, Field

        rec = step.odometry
        scan = step.scan
        pts = scan.points()
        keep = np.ones(len(pts), bool)
        if rec is not None and self.variant in rec.kept:
            keep = np.asarray(rec.kept[self.variant], bool)
        labels = step.frame.point_labels() if step.frame.labels is not None else np.ones(len(pts), np.uint8)
        dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "u1")])
        arr = np.zeros(int(keep.sum()), dtype=dtype)
        for i, c in enumerate("xyz"):
            arr[c] = pts[keep, i]
        arr["label"] = labels[keep]
        t = float(scan.meta.get("frame_time") or 0.0)
        sec = int(t)
        fields = tuple(Field(c, 4 * i, DATATYPE_CODES["f4"], 1) for i, c in enumerate("xyz"))
        fields += (Field("label", 12, DATATYPE_CODES["u1"], 1),)
        raw = arr.view(np.uint8).reshape(len(arr), dtype.itemsize)
        cloud = CloudMessage(
            raw=raw, points=arr, fields=fields, height=1, width=len(arr), point_step=dtype.itemsize,
            is_bigendian=False, is_dense=True, frame_id="lidar", stamp_sec=sec,
            stamp_nanosec=round((t - sec) * 1e9) % 10**9, seq=step.index,
        )  # fmt: skip
        self.writer.write_cloud(cloud, log_time_ns=int(t * 1e9))
        self.frames += 1

    def close(self, result: PipelineResult) -> None:
        self.writer.close()
