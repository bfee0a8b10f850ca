"""Running the online detectors' kernels on more than one core without numba's parallel loops.

With another process on one of two cores, numba's parallel loops ran 1.4x slower than serial code
(their workers wait for one another: 69.5 vs 50.0 ms a hdl64 sweep); here work is split into a
few large independent pieces, one per numba thread (``numba.get_num_threads()``, which
``NUMBA_NUM_THREADS`` sets; 1: everything in the calling thread), on plain threads that only
share whatever cores are free. The pieces must release the GIL (``nogil`` kernels) and write
disjoint outputs; every result is computed as in a serial run.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable

import numba


def in_threads(work: Callable[[int, int], object], n: int, min_chunk: int = 256, pieces: int = 4) -> None:
    """``work(lo, hi)`` over ``0..n`` in contiguous chunks on the numba threads
    (``numba.get_num_threads()``, which ``NUMBA_NUM_THREADS`` sets): as many threads as there are
    ``min_chunk`` items (at most the numba threads), each taking the next chunk when done with
    its last; ``pieces`` chunks per thread, so that a thread slowed by a heavier share of the items
    or by another process on its core does not hold the others up. The calling thread is one of
    them. ``work`` must release the GIL (a ``nogil`` kernel) and write disjoint outputs per item."""
    k = max(1, min(numba.get_num_threads(), n // max(1, min_chunk)))
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


def concurrently(background: Callable[[], object], foreground: Callable[[], object]) -> tuple[object, object]:
    """``(background(), foreground())``, the first on another thread when there is more than one
    numba thread; an exception in either is raised here."""
    if numba.get_num_threads() < 2:
        return background(), foreground()
    out: list[object] = [None]
    errors: list[BaseException] = []

    def run() -> None:
        try:
            out[0] = background()
        except BaseException as exc:  # re-raised in the calling thread
            errors.append(exc)

    thread = threading.Thread(target=run)
    thread.start()
    try:
        fg = foreground()
    finally:
        thread.join()
    if errors:
        raise errors[0]
    return out[0], fg
