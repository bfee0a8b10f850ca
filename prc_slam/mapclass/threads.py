"""Independent steps of the map classification side by side on plain threads.

Steps that need nothing of each other (the two shifted grids of the surface density, ground
beside the segmentation, foliage beside the posts) run on two threads when numba may use two
(``numba.get_num_threads()``, set by ``NUMBA_NUM_THREADS``; 1: one after the other in the
calling thread). Each step's heavy work is in ``nogil`` numba kernels or numpy, so the threads
share whatever cores are free; only the first step (in the calling thread) may call numba's
parallel kernels, the others call serial ones (numba's work-queue threading layer must not be
entered from two threads at once). Every result is computed as in a serial run: the steps
write no shared output.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numba


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

    if numba.get_num_threads() < 2 or len(steps) < 2:
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
