"""The processes a command leaves behind, found through /proc, and polling with a timeout."""

from __future__ import annotations

import os
import time
from collections.abc import Callable


def processes_under(sid: int) -> list[int]:
    """The live (not zombie) processes whose SID (field 6 of ``/proc/<pid>/stat``) is ``sid``: a
    process started with ``start_new_session=True`` and every process it started."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            found.append(int(entry))
    return found


def wait_until(test: Callable[[], object], timeout: float) -> bool:
    """Poll ``test`` every 0.1 s until it is true or ``timeout`` seconds have passed; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if test():
            return True
        time.sleep(0.1)
    return test()
