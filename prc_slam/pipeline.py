"""The per-frame loop composing the stages. Today: PRC classification of a sequence."""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from prc_slam.prc.config import PRCConfig
from prc_slam.prc import PRCStream, prc_block
from prc_slam.scan import Scan


@dataclass
class ClassifiedFrame:
    """One input frame with its PRC labels per slot and the PRC compute time spent on it.

    ``one_sided`` marks noise slots that meet one of the two support conditions of eq. (4)
    (thin poles, edges), as opposed to isolated returns.
    """

    scan: Scan
    labels: np.ndarray
    seconds: float
    one_sided: np.ndarray | None = None

    def point_labels(self) -> np.ndarray:
        """Labels per input point, in input order."""
        return self.scan.per_point(self.labels)

    def point_one_sided(self) -> np.ndarray:
        """``one_sided`` per input point (all False when unknown)."""
        if self.one_sided is None:
            return np.zeros(self.scan.n_points, dtype=bool)
        return self.scan.per_point(self.one_sided)


def classify_frames(scans: Iterable[Scan], config: PRCConfig) -> Iterator[ClassifiedFrame]:
    """Classify a sequence of scans with PRC, yielding each frame once all its slots are labelled.

    A spinning sensor's sweep is one block. A continuous sensor's (profiler's) scan lines form
    one stream cut into blocks of ``config.k`` lines regardless of frame boundaries, so the
    labels do not depend on how the recording was split into frames.
    """
    stream: PRCStream | None = None
    pending: list[tuple[Scan, int, np.ndarray, np.ndarray]] = []  # scan, first stream row, labels, one_sided
    next_row = 0
    spent = 0.0  # PRC time not yet attributed to a yielded frame
    for scan in scans:
        if not scan.sensor.continuous_rows:
            wrap = True if config.wrap_columns is None else config.wrap_columns
            t0 = time.perf_counter()
            res = prc_block(scan.ranges, config, sensor=scan.sensor, wrap=wrap)
            yield ClassifiedFrame(scan, res.labels, time.perf_counter() - t0, res.one_sided)
            continue
        if stream is None:
            stream = PRCStream(config, scan.sensor)
        elif scan.sensor.cols != stream.sensor.cols:
            raise ValueError(f"{scan.source}: {scan.sensor.cols} points per scan line, stream has {stream.sensor.cols}")
        pending.append((scan, next_row, np.zeros(scan.shape, dtype=np.uint8), np.zeros(scan.shape, dtype=bool)))
        next_row += scan.shape[0]
        t0 = time.perf_counter()
        blocks = stream.push(scan.ranges)
        spent += time.perf_counter() - t0
        for done, labels, one_sided in _complete(pending, blocks):
            yield ClassifiedFrame(done, labels, spent, one_sided)
            spent = 0.0
    if stream is not None:
        t0 = time.perf_counter()
        blocks = stream.flush()
        spent += time.perf_counter() - t0
        for done, labels, one_sided in _complete(pending, blocks):
            yield ClassifiedFrame(done, labels, spent, one_sided)
            spent = 0.0
        if pending:
            raise RuntimeError("PRC stream flushed with frames still unlabelled")


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
