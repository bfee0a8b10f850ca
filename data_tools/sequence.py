"""The Dataset protocol every reader implements, a base class for sequences of files, and the
:class:`Reader` entry by which each format joins the registry of :func:`data_tools.open_dataset`."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from prc_slam.scan import Scan


class Dataset(Protocol):
    """A sequence of Scans with optional ground-truth poses and frame times."""

    format: str
    name: str
    poses: np.ndarray | None
    times: np.ndarray | None

    def __len__(self) -> int: ...
    def __getitem__(self, i: int) -> Scan: ...
    def __iter__(self) -> Iterator[Scan]: ...


class SequenceBase:
    """Indexable, iterable sequence of Scans; subclasses implement ``__getitem__`` over ``files``."""

    files: list[Path]

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self) -> Iterator[Scan]:
        for i in range(len(self)):
            yield self[i]

    def __getitem__(self, i: int) -> Scan:
        raise NotImplementedError


#: the organiser's hints, taken by the readers of unorganised points (``--rows``, ``--cols``, ``--organize``)
ORGANISER_OPTIONS = ("rows", "cols", "organize_method")


def organiser_hints(options: dict[str, Any]) -> dict[str, Any]:
    """``rows``, ``cols`` and ``method`` for an :class:`~data_tools.organize.Organizer` (or a reader
    that makes one) from the reader options given."""
    rows, cols = options.get("rows"), options.get("cols")
    return {
        "rows": None if rows is None else int(str(rows)),
        "cols": None if cols is None else int(str(cols)),
        "method": str(options.get("organize_method") or "auto"),
    }


@dataclass(frozen=True)
class Reader:
    """One input format of the registry (:data:`data_tools.datasets.READERS`).

    Attributes
    ----------
    format : str
        Its name (``--format``).
    options : tuple of str
        The reader options it takes; another one given is an error, not ignored.
    detect : callable
        ``detect(path) -> bool``: whether ``path`` (which exists) is of this format; may raise
        :class:`~data_tools.errors.DataError` for an input of this kind that cannot be read (an empty
        capture, a pcap without its metadata), so that the message names the real problem.
    open : callable
        ``open(path, options) -> Dataset``, ``options`` the reader options given.
    """

    format: str
    options: tuple[str, ...]
    detect: Callable[[Path], bool]
    open: Callable[[Path, dict[str, Any]], Dataset]
