"""Progress that shows in a terminal (a rich bar) and in a log file or CI (plain lines).

When standard error is not a terminal, a line ``<task>: k/n frames, r frames/s, ETA s`` is
logged every ``every_s`` seconds and at the end, through the ``prc_slam`` logger, so it also
reaches ``--log-file``.
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
    """One counted task; ``advance()`` after every unit of work."""

    def __init__(self, description: str, total: int | None, bar: Progress | None, every_s: float) -> None:
        self.description, self.total, self.bar = description, total, bar
        self.done = 0
        self.every_s = every_s
        self.t0 = self.last = time.monotonic()
        self.id = None if bar is None else bar.add_task(description, total=total)

    def advance(self, n: int = 1) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.advance(self.id, n)
            return
        now = time.monotonic()
        if now - self.last >= self.every_s or (self.total is not None and self.done >= self.total):
            self.last = now
            log.info(self.line(now))

    def line(self, now: float | None = None) -> str:
        elapsed = max((now or time.monotonic()) - self.t0, 1e-9)
        rate = self.done / elapsed
        text = f"{self.description}: {self.done}" + (f"/{self.total}" if self.total else "") + f", {rate:.2f}/s"
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
