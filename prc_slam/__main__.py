"""The ``prc-slam`` console entry point.

It imports nothing heavy before taking over Ctrl-C and SIGTERM (:mod:`prc_slam.util.signals`), so
that an interrupt at any moment (also while numpy, numba or Open3D are still loading, where it
surfaces as an ``ImportError``) ends with one line ``error: interrupted ...`` and exit code 130
(143 for SIGTERM), the process's children ended, and no tear-down noise from half-loaded
extensions.
"""

from __future__ import annotations

import os
import signal
import sys

from prc_slam.util import signals
from prc_slam.util.signals import REDELIVER_S, _in_native_callback  # noqa: F401  (kept importable from here)

_interrupted = False


def _on_sigint(signum, frame):
    """SIGINT and SIGTERM: :func:`prc_slam.util.signals.on_signal`, remembered for the exit."""
    global _interrupted
    _interrupted = True
    signals.on_signal(signum, frame)


def _exit_interrupted() -> None:
    sys.stderr.write("error: interrupted\n")
    sys.stderr.flush()
    sys.stdout.flush()
    signals.end_children()
    os._exit(signals.exit_code())


def main() -> None:
    signals.install(_on_sigint)
    try:
        from prc_slam.cli import app

        app()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if code == 130:  # the command said "error: interrupted" already
            sys.stdout.flush()
            sys.stderr.flush()
            signals.end_children()
            os._exit(signals.exit_code())
        if _interrupted:  # Ctrl-C while the command was finishing
            _exit_interrupted()
        for sig in signals.HANDLED:  # done: a Ctrl-C or SIGTERM during tear-down changes nothing
            signal.signal(sig, signal.SIG_IGN)
        raise
    except BaseException:
        if _interrupted:
            _exit_interrupted()
        raise


if __name__ == "__main__":  # pragma: no cover
    main()
