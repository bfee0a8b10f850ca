"""LAS/LAZ files through laspy: the LAZ backend (``lazrs``, with an error that says what to install),
and :func:`open_las`, which turns an unreadable file into a one-line error naming it."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from data_tools.errors import DataError


def laz_backend(path: str | Path) -> tuple | None:
    """The laspy LAZ backends to use for ``path``: None for ``.las``; for ``.laz`` the ``lazrs``
    backends (parallel first) when installed, else any other laspy can find.

    Raises
    ------
    DataError
        For a ``.laz`` when no backend is installed (laspy's own message, "No LazBackend selected",
        does not say what to install).
    """
    path = Path(path)
    if path.suffix.lower() != ".laz":
        return None
    import laspy

    available = laspy.LazBackend.detect_available()
    preferred = tuple(b for b in (laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs) if b in available)
    if preferred:
        return preferred
    if available:
        return tuple(available)
    raise DataError(f"{path}: LAZ needs a LAZ backend for laspy: install lazrs (pip install lazrs)")


@contextmanager
def open_las(path: str | Path) -> Iterator[Any]:
    """``laspy.open(path)`` for reading, with :func:`laz_backend`'s backend.

    Raises
    ------
    DataError
        The file is not a readable LAS/LAZ file (laspy's, lazrs' or the system's error, in one line).
    """
    import laspy

    path = Path(path)
    backend = laz_backend(path)
    try:
        with laspy.open(path, laz_backend=backend) as f:
            yield f
    except DataError:
        raise
    except (laspy.LaspyException, ValueError, OSError, RuntimeError) as exc:  # lazrs errors are RuntimeErrors
        raise DataError(f"{path}: not a readable LAS file ({exc})") from exc
