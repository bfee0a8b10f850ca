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

_interrupted = False


def _on_sigint(signum, frame):
    global _interrupted
    _interrupted = True
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
