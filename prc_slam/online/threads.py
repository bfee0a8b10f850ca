"""Running the online detectors' kernels on more than one core without numba's parallel loops.

With another process on one of two cores, numba's parallel loops ran 1.4x slower than serial code
(their workers wait for one another: 69.5 vs 50.0 ms a hdl64 sweep); here work is split into a
few large independent pieces, one per numba thread (``numba.get_num_threads()``, which
``NUMBA_NUM_THREADS`` sets; 1: everything in the calling thread), on plain threads that only
share whatever cores are free. The pieces must release the GIL (``nogil`` kernels) and write
disjoint outputs; every result is computed as in a serial run.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numba


def in_threads(work: Callable[[int, int], object], n: int, min_chunk: int = 256) -> None:
    """``work(lo, hi)`` over ``0..n`` in contiguous chunks, one per numba thread
    (``numba.get_num_threads()``, which ``NUMBA_NUM_THREADS`` sets), each chunk at least
    ``min_chunk`` items: the calling thread takes the first chunk, plain threads the others.
    ``work`` must release the GIL (a ``nogil`` kernel) and write disjoint outputs per item."""
    k = max(1, min(numba.get_num_threads(), n // max(1, min_chunk)))
    if k == 1:
        work(0, n)
        return
    bounds = [n * i // k for i in range(k + 1)]
    errors: list[BaseException] = []

    def run(lo: int, hi: int) -> None:
        try:
            work(lo, hi)
        except BaseException as exc:  # re-raised in the calling thread
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(bounds[i], bounds[i + 1])) for i in range(1, k)]
    for t in threads:
        t.start()
    run(bounds[0], bounds[1])
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
