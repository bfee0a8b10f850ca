"""Running independent pieces of work on more than one core without numba's parallel loops.

With another process on one of two cores, numba's parallel loops ran 1.4x slower than serial code
(their workers wait for one another: 69.5 vs 50.0 ms a hdl64 sweep of the online detectors); here
work is split into a few large independent pieces on plain threads that only share whatever cores
are free: chunks of items (:func:`in_threads`: the online detectors' scan lines) or whole steps
(:func:`side_by_side`: the curb and car detectors, steps of the map classification). As many
threads as numba may use (``numba.get_num_threads()``, which ``NUMBA_NUM_THREADS`` sets; 1:
everything in the calling thread, one after the other). The pieces must release the GIL
(``nogil`` kernels, numpy) and write disjoint outputs; every result is computed as in a serial
run; :class:`ThreadUse` sends a caller's steps to the threads only while they do not wait for a
core. Steps run here call serial kernels only (numba's work-queue threading layer must not be
entered from two threads at once).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numba


def numba_threads() -> int:
    """``numba.get_num_threads()`` without starting numba's thread pool: until a parallel kernel
    (or ``numba.set_num_threads``) has started it, the configured count (``NUMBA_NUM_THREADS``).
    Asking the pool starts its OpenMP threads, after which this process can no longer be forked
    safely (:mod:`prc_slam.util.frame_process`); splitting work across plain threads does not need it."""
    from numba.np.ufunc import parallel

    if getattr(parallel, "_is_initialized", True):
        return numba.get_num_threads()
    return int(numba.config.NUMBA_NUM_THREADS)


def in_threads(work: Callable[[int, int], object], n: int, min_chunk: int = 256, pieces: int = 4) -> None:
    """``work(lo, hi)`` over ``0..n`` in contiguous chunks on the numba threads
    (``numba.get_num_threads()``, which ``NUMBA_NUM_THREADS`` sets): as many threads as there are
    ``min_chunk`` items (at most the numba threads), each taking the next chunk when done with
    its last; ``pieces`` chunks per thread, so that a thread slowed by a heavier share of the items
    or by another process on its core does not hold the others up. The calling thread is one of
    them. ``work`` must release the GIL (a ``nogil`` kernel) and write disjoint outputs per item."""
    k = max(1, min(numba_threads(), n // max(1, min_chunk)))
    if k == 1:
        work(0, n)
        return
    m = k * max(1, pieces)
    bounds = [n * i // m for i in range(m + 1)]
    turn = itertools.count()  # the next chunk: one atomic step under the GIL
    errors: list[BaseException] = []

    def run() -> None:
        try:
            for i in iter(lambda: next(turn), None):
                if i >= m or errors:
                    return
                work(bounds[i], bounds[i + 1])
        except BaseException as exc:  # re-raised in the calling thread
            errors.append(exc)

    threads = [threading.Thread(target=run) for _ in range(k - 1)]
    for t in threads:
        t.start()
    run()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


def side_by_side(*steps: Callable[[], Any]) -> tuple[list[Any], list[float]]:
    """Results of ``steps`` (called without arguments) and the seconds each took: the first
    in the calling thread, the others each on a thread of its own when numba may use more than
    one thread, else one after the other. An exception in any is raised here."""
    results: list[Any] = [None] * len(steps)
    seconds = [0.0] * len(steps)
    errors: list[BaseException] = []

    def run(k: int) -> None:
        t = time.perf_counter()
        try:
            results[k] = steps[k]()
        except BaseException as exc:  # re-raised in the calling thread
            errors.append(exc)
        seconds[k] = time.perf_counter() - t

    if numba_threads() < 2 or len(steps) < 2:
        for k in range(len(steps)):
            run(k)
    else:
        threads = [threading.Thread(target=run, args=(k,)) for k in range(1, len(steps))]
        for t in threads:
            t.start()
        run(0)
        for t in threads:
            t.join()
    if errors:
        raise errors[0]
    return results, seconds


T = TypeVar("T")


class ThreadUse:
    """Whether a caller's steps go to the threads of :func:`in_threads` / :func:`side_by_side`:
    only with ``numba.get_num_threads() >= 2`` and at least ``min_items`` items, and not while
    paused. The results are the same either way; the time is not: when another process keeps the
    other cores busy, a step waiting for a thread that is off its core costs more than it saves.
    So every threaded step is watched: one whose wall time exceeds ``slack`` times its CPU time
    plus ``grace_s`` (its thread waited for a core) makes the next ``pause`` steps run serially;
    the pause doubles (up to ``pause_max``) while steps keep waiting, and shrinks by one with
    every step that did not wait."""

    def __init__(
        self, min_items: int, pause_min: int = 6, pause_max: int = 96, slack: float = 1.5, grace_s: float = 1e-3
    ) -> None:
        self.min_items = min_items
        self.pause_min, self.pause_max, self.slack, self.grace_s = pause_min, pause_max, slack, grace_s
        self.pause = pause_min
        self.serial_left = 0
        self.waited = 0  # threaded steps that waited for a core (for reports)

    def use(self, items: int) -> bool:
        if items < self.min_items or numba_threads() < 2:
            return False
        if self.serial_left > 0:
            self.serial_left -= 1
            return False
        return True

    def watched(self, step: Callable[..., T]) -> Callable[..., T]:
        """``step`` timed on its thread: wall time well above CPU time pauses the threads."""

        def run(*a: object) -> T:
            w0, c0 = time.perf_counter(), time.thread_time()
            try:
                return step(*a)
            finally:
                wall, cpu = time.perf_counter() - w0, time.thread_time() - c0
                if wall > self.slack * cpu + self.grace_s:
                    self.waited += 1
                    self.serial_left = self.pause
                    self.pause = min(2 * self.pause, self.pause_max)
                else:
                    self.pause = max(self.pause - 1, self.pause_min)

        return run
