"""The next frame made in a second process (fork) instead of a second thread.

KISS-ICP's Python bindings hold the GIL for the whole of each C++ call (voxelising, registering,
updating the map). A thread that reads, organises and classifies the next frame beside the
registration gets the GIL only between those calls, and every Python step between its numba
kernels waits for one: beside a KISS-ICP loop, organising and classifying a KITTI sweep took
51 ms instead of 7.6 ms on a thread, 8.6 ms in a second process (measured on this project's
2-core machine; ``docs/RESULTS.md``). :class:`ForkedNextFrame` keeps the interface of
:class:`prc_slam.pipeline.NextFrame` (``start``, ``wait``, ``take``, ``charged``, ``seconds``)
and makes the frames in a child forked from the caller, which holds the source, the organiser
and PRC's state from then on; the frames come back pickled. Log records and warnings of the
child are passed on to the caller's handlers with each frame; errors are raised again by
``take`` in the caller, as with the thread.

Fork is used (the child continues the caller's iterators where they stand), so it is only taken
where it is safe: on POSIX, from the main thread of a process that is not itself a daemonic
worker (Dask's), and before numba's OpenMP threads have started in the caller (GNU OpenMP does
not survive a fork). :func:`can_fork` says whether it is; elsewhere the next frame is made on a
thread, as before.

The child never outlives the caller: it is killed when the caller ends, however it ends
(``prctl(PR_SET_PDEATHSIG)`` on Linux, a watch of its parent elsewhere), and it ends at the end
of file when the caller closes the pipe.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing as mp
import os
import pickle
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

#: prctl(2) option: the signal the kernel sends this process when its parent ends (Linux)
PR_SET_PDEATHSIG = 1
#: seconds between the child's checks that its parent is still there (where prctl is missing)
PARENT_POLL_S = 1.0

#: the child's scheduling niceness: the registration beside it is the critical path, and on two
#: cores KISS-ICP's threads use both; at the caller's priority the child's reading and PRC slowed
#: them (simulated urban drive: ICP 7.7 -> 12.3 ms a frame, prc time 0.51 -> 0.61 of raw's), at
#: the lowest it takes what they leave (ICP 8.8 ms, 0.49)
CHILD_NICE = 19


class FrameProcessEnded(RuntimeError):
    """The child making the frames ended without being asked to (killed, out of memory, crashed)."""


def can_fork() -> tuple[bool, str]:
    """Whether a frame process can be forked here, and why not."""
    if os.name != "posix" or "fork" not in mp.get_all_start_methods():
        return False, "no fork on this platform"
    if mp.current_process().daemon:
        return False, "a daemonic process (a Dask or multiprocessing worker) cannot start one"
    if threading.current_thread() is not threading.main_thread():
        return False, "not on the main thread (a fork there copies other threads' locks)"
    try:
        from numba.np.ufunc import parallel
    except Exception:  # numba's internals moved: do not guess
        return False, "numba's threading state is unknown"
    if getattr(parallel, "_is_initialized", True):
        return False, "numba's parallel threads already run in this process (OpenMP does not survive a fork)"
    return True, ""


class _Collect(logging.Handler):
    """The child's log records, kept to be passed on with the next frame."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((record.name, record.levelno, record.getMessage()))

    def drain(self) -> list[tuple[str, int, str]]:
        out, self.records = self.records, []
        return out


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")


def die_with_parent(parent: int) -> bool:
    """In a forked child: be killed (SIGKILL) when the parent ``parent`` ends, whatever ends it
    (SIGTERM, SIGKILL, a crash). On Linux through ``prctl(PR_SET_PDEATHSIG)``, then a check that
    the parent did not already end before it took effect; returns whether prctl took it (else the
    caller watches :func:`os.getppid`). Ends the child at once when the parent has gone."""
    armed = False
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
        except (OSError, AttributeError):  # no libc prctl: the caller polls
            armed = False
    if os.getppid() != parent:  # the parent ended before the death signal was armed
        os._exit(1)
    return armed


def _watch_parent(parent: int) -> None:
    """A daemon thread in the child: end the child when its parent has gone (no prctl)."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="prc-slam-parent-watch", daemon=True).start()


def _serve(
    conn: Any,
    make: Callable[[], Any],
    state: Callable[[], Any],
    warnings_to: list[str],
    parent: int = 0,
    parent_end: Any = None,
) -> None:
    """The child: make a frame for every request, send it with its intervals, logs and state.
    It ends with its parent (:func:`die_with_parent`), and when the parent closes the pipe: the
    child closes its copy of the parent's end, so the parent's exit is an end of file here."""
    if parent and not die_with_parent(parent):
        _watch_parent(parent)
    if parent_end is not None:
        parent_end.close()
    from prc_slam.util.signals import reset_in_child

    reset_in_child()  # SIGTERM ends the child; the parent's signal watchdog is not told
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's to handle
    os.nice(CHILD_NICE)
    collect = _Collect()
    root = logging.getLogger()
    for logger in [root, *(v for v in logging.Logger.manager.loggerDict.values() if isinstance(v, logging.Logger))]:
        logger.handlers = []
        logger.propagate = logger is not root
    root.addHandler(collect)  # the levels stay the caller's
    try:
        frames, failed = make(), None
    except BaseException as exc:  # answered to every request
        frames, failed = None, _portable(exc)
    try:
        while conn.recv():
            item, error, charged, seconds = None, failed, (), 0.0
            if frames is not None:
                try:
                    item = frames.take()
                except BaseException as exc:  # raised again by the caller's take()
                    error = _portable(exc)
                charged, seconds = frames.charged, frames.seconds
            msg = (item, charged, seconds, collect.drain(), list(warnings_to), state(), error)
            warnings_to.clear()
            try:
                conn.send(msg)
            except Exception as exc:  # a frame that cannot be pickled
                conn.send((None, (), 0.0, collect.drain(), [], state(), RuntimeError(f"frame not sent: {exc}")))
    except (EOFError, OSError):  # the caller has gone
        return


class ForkedNextFrame:
    """:class:`prc_slam.pipeline.NextFrame` in a forked child.

    Parameters
    ----------
    make : callable
        Called in the child: returns the :class:`~prc_slam.pipeline.NextFrame` to take frames from
        (built on the caller's source, which the child continues).
    state : callable
        Called in the child after each frame: what the caller's ``absorb`` receives (e.g. the
        skipped frames and the organiser's counts, which the source writes as it goes).
    absorb : callable
        Called in the caller with each ``state()``.
    warnings_to : list
        The list the child's warnings are appended to (the child's copy is sent and emptied).
    warn : callable(str)
        Receives those warnings in the caller.
    """

    def __init__(
        self,
        make: Callable[[], Any],
        state: Callable[[], Any],
        absorb: Callable[[Any], None],
        warnings_to: list[str],
        warn: Callable[[str], None],
    ) -> None:
        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve,
            args=(child, make, state, warnings_to, os.getpid(), self._conn),
            name="prc-slam-frames",
            daemon=True,
        )
        self._proc.start()
        child.close()
        self._absorb, self._warn = absorb, warn
        self._asked = False
        self._got: tuple[Any, BaseException | None] | None = None
        self.seconds = 0.0
        self.charged: tuple[tuple[float, float], ...] = ()

    def _ended(self, exc: BaseException) -> FrameProcessEnded:
        self._asked = False
        self._proc.join(1.0)
        code = self._proc.exitcode
        return FrameProcessEnded(
            f"the process making the frames ended (exit code {code}{', a signal' if code and code < 0 else ''})"
            + (f": {exc}" if str(exc) else "")
        )

    def _receive(self) -> None:
        try:
            item, charged, seconds, records, warned, state, error = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise self._ended(exc) from None
        self._asked = False
        self.charged, self.seconds = tuple(charged), seconds
        for name, level, text in records:
            logging.getLogger(name).log(level, text)
        for text in warned:
            self._warn(text)
        self._absorb(state)
        self._got = (item, error)

    def start(self) -> None:
        """Ask the child for the next frame (nothing when already asked or made)."""
        if not self._asked and self._got is None:
            try:
                self._conn.send(True)
            except OSError as exc:  # the child has gone: said by the next take()
                self._got = (None, self._ended(exc))
                return
            self._asked = True

    def wait(self) -> float:
        """Wait for the frame asked by :meth:`start`; its wall time (s), 0 if none was asked. A
        child that has ended is raised by the next :meth:`take`, in its turn."""
        if not self._asked:
            return 0.0
        try:
            self._receive()
        except FrameProcessEnded as exc:
            self.charged, self.seconds, self._got = (), 0.0, (None, exc)
        return self.seconds

    def take(self) -> Any:
        """The next frame (None after the last), made now unless :meth:`start` asked for it."""
        self.start()
        if self._got is None:
            self._receive()
        (item, error), self._got = self._got, None
        if error is not None:
            raise error
        return item

    def close(self) -> None:
        """End the child (it finishes the frame it is making first, up to a few seconds)."""
        if self._proc.is_alive():
            try:
                if self._asked:
                    self._conn.recv()
                self._conn.send(False)
            except Exception:  # a broken pipe or a message cut by an interrupt: terminated below
                pass
            self._proc.join(5.0)
            if self._proc.is_alive():
                self._proc.terminate()
                self._proc.join(1.0)
        self._conn.close()
