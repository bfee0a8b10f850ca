"""Progress that shows in a terminal (a rich bar) and in a log file or CI (plain lines).

When standard error is not a terminal, a line ``<task>: k/n, r/s, ETA s`` is logged every
``every_s`` seconds and at the end, through the ``prc_slam`` logger, so it also reaches
``--log-file``; rate and ETA leave out the first unit, which pays the start-up (:class:`Task`).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

log = logging.getLogger("prc_slam.progress")
console = Console(stderr=True, soft_wrap=True)


class Task:
    """One counted task; ``advance()`` after every unit of work.

    Rate and ETA are measured from the end of the first unit on: the first frame also pays
    the start-up (numba compiling the kernels, a minute on a cold cache), which would make an
    ETA taken from it alone many times too long; until a second unit is done no ETA is shown."""

    def __init__(self, description: str, total: int | None, bar: Progress | None, every_s: float) -> None:
        self.description, self.total, self.bar = description, total, bar
        self.done = 0
        self.every_s = every_s
        self.t0 = self.last = time.monotonic()
        self.first: tuple[float, int] | None = None  # (time, units done) at the end of the first advance
        self.id = None if bar is None else bar.add_task(description, total=total)

    def advance(self, n: int = 1) -> None:
        self.done += n
        now = time.monotonic()
        if self.first is None:
            self.first = (now, self.done)
        if self.bar is not None:
            self.bar.advance(self.id, n)
            return
        if now - self.last >= self.every_s or (self.total is not None and self.done >= self.total):
            self.last = now
            log.info(self.line(now))

    def steady_rate(self, now: float) -> float | None:
        """Units per second since the first unit was done (None before a second one)."""
        if self.first is None or self.done <= self.first[1] or now <= self.first[0]:
            return None
        return (self.done - self.first[1]) / (now - self.first[0])

    def line(self, now: float | None = None) -> str:
        now = time.monotonic() if now is None else now
        text = f"{self.description}: {self.done}" + (f"/{self.total}" if self.total else "")
        rate = self.steady_rate(now)
        if rate is None:
            if self.first is not None and self.total and self.done < self.total:
                took = self.first[0] - self.t0
                text += f", the first in {took:.1f} s with the start-up (ETA from the next one on)"
            elif self.done:
                text += f", {self.done / max(now - self.t0, 1e-9):.2f}/s"
            return text
        text += f", {rate:.2f}/s"
        if self.total and rate > 0 and self.done < self.total:
            text += f", ETA {(self.total - self.done) / rate:.0f} s"
        return text


class Reporter:
    """Hands out :class:`Task` objects, drawn as bars on a terminal, logged as lines elsewhere."""

    def __init__(self, bar: Progress | None, every_s: float) -> None:
        self.bar, self.every_s = bar, every_s

    def task(self, description: str, total: int | None = None) -> Task:
        return Task(description, total, self.bar, self.every_s)


@contextmanager
def progress(every_s: float = 10.0, terminal: bool | None = None) -> Iterator[Reporter]:
    """A progress reporter for the duration of a job (a bar only on a terminal)."""
    terminal = console.is_terminal and sys.stderr.isatty() if terminal is None else terminal
    if not terminal:
        yield Reporter(None, every_s)
        return
    bar = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    )
    with bar:
        yield Reporter(bar, every_s)
