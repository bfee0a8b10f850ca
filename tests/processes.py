"""The processes a command leaves behind, found through /proc, and polling with a timeout."""

from __future__ import annotations

import time
from collections.abc import Callable

from prc_slam.util.signals import process_table


def processes_under(sid: int) -> list[int]:
    """The live (not zombie) processes whose SID (field 6 of ``/proc/<pid>/stat``) is ``sid``: a
    process started with ``start_new_session=True`` and every process it started."""
    return [pid for pid, state, _, session in process_table() if session == sid and state != "Z"]


def wait_until(test: Callable[[], object], timeout: float) -> bool:
    """Poll ``test`` every 0.1 s until it is true or ``timeout`` seconds have passed; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if test():
            return True
        time.sleep(0.1)
    return test()
