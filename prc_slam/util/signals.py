"""Ctrl-C and SIGTERM in the ``prc-slam`` process: every interrupt ends the run.

Standard library only (the launcher installs it before anything heavy is imported).

- :func:`install` makes SIGINT and SIGTERM raise ``KeyboardInterrupt`` in the main thread (a
  SIGTERM ends the run as a Ctrl-C does: the partial outputs are written, children reaped; the
  exit code is then 143 instead of 130).
- A watchdog thread learns of every signal through :func:`signal.set_wakeup_fd` (written by the
  interpreter's C-level handler, whatever the main thread does). When the main thread has not run
  the Python handler :data:`STUCK_S` seconds after a signal, it is blocked in native code that
  does not return (e.g. Rerun's sender waiting forever for a viewer that has gone, "Sender has been
  blocked ..."): the watchdog then ends the process's children, prints one line and exits.
- :func:`frame_boundaries` (used by the jobs around their per-frame loop) holds a first interrupt
  until the frame in progress is done, so that what was produced covers whole frames: the job
  calls the returned ``check`` after each frame, which raises ``KeyboardInterrupt`` there. A second
  interrupt, or :data:`DEFER_S` seconds without a frame boundary, raises at once.
"""

from __future__ import annotations

import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: seconds after which a signal the main thread did not handle ends the process from the watchdog
STUCK_S = 5.0
#: seconds a first interrupt waits for the end of the frame in progress
DEFER_S = 5.0
#: seconds after which a Ctrl-C that arrived inside a native callback is delivered again
REDELIVER_S = 0.05
HANDLED = (signal.SIGINT, signal.SIGTERM)


class _State:
    """What the handler, the watchdog and the jobs share."""

    def __init__(self) -> None:
        self.interrupted = False
        self.signum: int | None = None  # the last signal handled
        self.received = 0  # signals seen by the watchdog
        self.handled = 0  # signals handled by the Python handler (main thread)
        self.unhandled_since: float | None = None
        self.deferring = False
        self.pending_since: float | None = None  # a deferred interrupt waits for a frame boundary
        self.redelivered = False
        self.installed = False
        self.handler: Callable | None = None
        self.lock = threading.Lock()


state = _State()


def exit_code() -> int:
    """The exit code of an interrupted run: 130 for Ctrl-C, 143 for SIGTERM."""
    return 128 + int(signal.SIGTERM) if state.signum == signal.SIGTERM else 130


def _in_native_callback(frame) -> bool:
    """Whether the signal arrived in Python code that native code called back: llvmlite's ctypes
    callbacks while numba compiles, where a raised exception is printed as "Exception ignored ...
    Traceback" and dropped."""
    return frame is not None and "llvmlite" in frame.f_code.co_filename


def on_signal(signum: int, frame) -> None:
    """The handler of SIGINT and SIGTERM: raise ``KeyboardInterrupt`` (held until the next frame
    boundary inside :func:`frame_boundaries`, delivered again after a native callback)."""
    with state.lock:
        state.handled += 1
        if state.handled >= state.received:
            state.unhandled_since = None
    state.interrupted = True
    state.signum = signum
    if _in_native_callback(frame):  # delivered again once the callback has returned
        timer = threading.Timer(REDELIVER_S, os.kill, (os.getpid(), signum))
        timer.daemon = True
        timer.start()
        return
    if state.deferring and state.pending_since is None:
        state.pending_since = time.monotonic()
        return
    raise KeyboardInterrupt


@contextmanager
def frame_boundaries() -> Iterator[Callable[[], None]]:
    """Hold a first interrupt until the next frame boundary; yields the ``check`` to call after
    each frame (raises ``KeyboardInterrupt`` when an interrupt waits). Outside the main thread, or
    when :func:`install` was not called (library use), ``check`` does nothing and interrupts are
    raised where they land."""
    active = state.installed and threading.current_thread() is threading.main_thread()

    def check() -> None:
        if active and state.pending_since is not None:
            state.pending_since = None
            state.deferring = False
            raise KeyboardInterrupt

    if not active:
        yield check
        return
    state.deferring, state.pending_since, state.redelivered = True, None, False
    try:
        yield check
        check()  # an interrupt that came after the last frame
    finally:
        state.deferring, state.pending_since = False, None


def process_table() -> list[tuple[int, str, int, int]]:
    """``(pid, state, ppid, session id)`` of every process in ``/proc`` (Linux; empty elsewhere)."""
    table = []
    try:
        entries = os.listdir("/proc")
    except OSError:
        return table
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        table.append((int(entry), fields[0], int(fields[1]), int(fields[3])))
    return table


def children() -> list[int]:
    """The pids of this process's children in its own session (Linux; empty elsewhere). A viewer
    started in a session of its own is not among them."""
    me, sid = os.getpid(), os.getsid(0)
    return [pid for pid, _, ppid, session in process_table() if ppid == me and session == sid]


def end_children(grace: float = 2.0) -> None:
    """SIGTERM to every child of this process (its own session), SIGKILL to those left after
    ``grace`` seconds, and reap them."""
    pids = children()
    for pid in pids:
        try:
            os.kill(pid, signal.SIGTERM)
        except OSError:
            pass
    deadline = time.monotonic() + grace
    while pids and time.monotonic() < deadline:
        pids = [pid for pid in pids if not _reaped(pid)]
        time.sleep(0.05)
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except OSError:
            pass


def _reaped(pid: int) -> bool:
    try:
        done, _ = os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:  # not ours to wait for (reaped elsewhere): gone when /proc says so
        return not os.path.exists(f"/proc/{pid}")
    return done == pid


def _force_exit() -> None:
    """The main thread is stuck in native code: end the children, say so, exit."""
    sys.stderr.write(
        "error: interrupted; the run was stuck in a native call that did not return (e.g. a Rerun viewer that "
        "stopped taking data), so nothing more was written\n"
    )
    sys.stderr.flush()
    end_children()
    os._exit(exit_code())


def _watch(fd: int) -> None:
    """The watchdog thread: count the signals, end the process when the main thread cannot handle
    them, deliver a deferred interrupt again when no frame boundary came."""
    while True:
        ready, _, _ = select.select([fd], [], [], 0.25)
        now = time.monotonic()
        if ready:
            try:
                data = os.read(fd, 512)
            except OSError:
                return
            # only the signals our handler is to handle (a job may install its own for a while)
            ours = [b for b in data if b in HANDLED and signal.getsignal(b) is state.handler]
            got = len(ours)
            if got:
                with state.lock:
                    state.signum = state.signum or ours[-1]  # the exit code's, if the handler never runs
                    state.received += got
                    if state.unhandled_since is None and state.received > state.handled:
                        state.unhandled_since = now
        with state.lock:
            stuck = state.unhandled_since is not None and now - state.unhandled_since > STUCK_S
        if stuck:
            _force_exit()
        pending = state.pending_since
        if pending is not None and not state.redelivered and now - pending > DEFER_S:
            state.redelivered = True  # the frame in progress does not end: raise where the main thread is
            os.kill(os.getpid(), state.signum or signal.SIGINT)


def install(handler: Callable = on_signal) -> None:
    """Install ``handler`` (:func:`on_signal` or a function calling it) for SIGINT and SIGTERM and
    start the watchdog (main thread only)."""
    for sig in HANDLED:
        signal.signal(sig, handler)
    state.installed, state.handler = True, handler
    if os.name != "posix":  # pragma: no cover - the watchdog needs a pipe the C handler can write
        return
    rfd, wfd = os.pipe()
    os.set_blocking(wfd, False)
    try:
        signal.set_wakeup_fd(wfd, warn_on_full_buffer=False)
    except ValueError:  # pragma: no cover - not the main thread
        os.close(rfd)
        os.close(wfd)
        return
    threading.Thread(target=_watch, args=(rfd,), name="prc-slam-signals", daemon=True).start()


def reset_in_child() -> None:
    """In a forked child: the default handlers and no wakeup pipe (the parent's watchdog must not
    read the child's signals)."""
    try:
        signal.set_wakeup_fd(-1)
    except ValueError:  # pragma: no cover - not the main thread
        pass
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    state.installed, state.deferring, state.pending_since = False, False, None
