"""The per-frame loop composing the stages. Today: PRC classification of a sequence."""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from prc_slam.config import PRCConfig
from prc_slam.prc import PRCStream, prc_block
from prc_slam.scan import Scan


@dataclass
class ClassifiedFrame:
    """One input frame with its PRC labels per slot and the PRC compute time spent on it."""

    scan: Scan
    labels: np.ndarray
    seconds: float

    def point_labels(self) -> np.ndarray:
        """Labels per input point, in input order."""
        return self.scan.per_point(self.labels)


def classify_frames(scans: Iterable[Scan], config: PRCConfig) -> Iterator[ClassifiedFrame]:
    """Classify a sequence of scans with PRC, yielding each frame once all its slots are labelled.

    A spinning sensor's sweep is one block. A continuous sensor's (profiler's) scan lines form
    one stream cut into blocks of ``config.k`` lines regardless of frame boundaries, so the
    labels do not depend on how the recording was split into frames.
    """
    stream: PRCStream | None = None
    pending: list[tuple[Scan, int, np.ndarray]] = []  # scan, its first stream row, its labels
    next_row = 0
    spent = 0.0  # PRC time not yet attributed to a yielded frame
    for scan in scans:
        if not scan.sensor.continuous_rows:
            wrap = True if config.wrap_columns is None else config.wrap_columns
            t0 = time.perf_counter()
            labels = prc_block(scan.ranges, config, sensor=scan.sensor, wrap=wrap).labels
            yield ClassifiedFrame(scan, labels, time.perf_counter() - t0)
            continue
        if stream is None:
            stream = PRCStream(config, scan.sensor)
        elif scan.sensor.cols != stream.sensor.cols:
            raise ValueError(f"{scan.source}: {scan.sensor.cols} points per scan line, stream has {stream.sensor.cols}")
        pending.append((scan, next_row, np.zeros(scan.shape, dtype=np.uint8)))
        next_row += scan.shape[0]
        t0 = time.perf_counter()
        blocks = stream.push(scan.ranges)
        spent += time.perf_counter() - t0
        for done, labels in _complete(pending, blocks):
            yield ClassifiedFrame(done, labels, spent)
            spent = 0.0
    if stream is not None:
        t0 = time.perf_counter()
        blocks = stream.flush()
        spent += time.perf_counter() - t0
        for done, labels in _complete(pending, blocks):
            yield ClassifiedFrame(done, labels, spent)
            spent = 0.0
        if pending:
            raise RuntimeError("PRC stream flushed with frames still unlabelled")


def _complete(pending: list[tuple[Scan, int, np.ndarray]], blocks: list) -> list[tuple[Scan, np.ndarray]]:
    """Copy block labels into the pending frames; pop and return the frames now complete."""
    for block in blocks:
        b0, b1 = block.row0, block.row0 + block.labels.shape[0]
        for _scan, f0, labels in pending:
            lo, hi = max(b0, f0), min(b1, f0 + labels.shape[0])
            if lo < hi:
                labels[lo - f0 : hi - f0] = block.labels[lo - b0 : hi - b0]
    if not blocks:
        return []
    done_rows = blocks[-1].row0 + blocks[-1].labels.shape[0]
    out = []
    while pending and pending[0][1] + pending[0][2].shape[0] <= done_rows:
        scan, _, labels = pending.pop(0)
        out.append((scan, labels))
    return out
