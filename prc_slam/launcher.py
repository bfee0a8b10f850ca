"""The ``prc-slam`` console entry point.

It imports nothing heavy before taking over Ctrl-C, so that an interrupt at any moment (also
while numpy, numba or Open3D are still loading, where it surfaces as an ``ImportError``) ends
with one line ``error: interrupted`` and exit code 130, and no tear-down noise from half-loaded
extensions.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

_interrupted = False
#: seconds after which a Ctrl-C that arrived inside a native callback is delivered again
REDELIVER_S = 0.05


def _in_native_callback(frame) -> bool:
    """Whether the signal arrived in Python code that native code called back: llvmlite's ctypes
    callbacks while numba compiles, where a raised exception is printed as "Exception ignored ...
    Traceback" and dropped."""
    return frame is not None and "llvmlite" in frame.f_code.co_filename


def _on_sigint(signum, frame):
    global _interrupted
    _interrupted = True
    if _in_native_callback(frame):  # delivered again once the callback has returned
        timer = threading.Timer(REDELIVER_S, os.kill, (os.getpid(), signal.SIGINT))
        timer.daemon = True
        timer.start()
        return
    raise KeyboardInterrupt


def _exit_interrupted() -> None:
    sys.stderr.write("error: interrupted\n")
    sys.stderr.flush()
    sys.stdout.flush()
    os._exit(130)


def main() -> None:
    signal.signal(signal.SIGINT, _on_sigint)
    try:
        from prc_slam.cli import app

        app()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if code == 130:  # the command said "error: interrupted" already
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(130)
        if _interrupted:  # Ctrl-C while the command was finishing
            _exit_interrupted()
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # done: a Ctrl-C during tear-down changes nothing
        raise
    except BaseException:
        if _interrupted:
            _exit_interrupted()
        raise


if __name__ == "__main__":  # pragma: no cover
    main()
