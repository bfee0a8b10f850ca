"""The Dataset protocol every reader implements, and a base class for sequences of files."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

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
