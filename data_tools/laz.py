"""The LAZ backend for laspy (``lazrs``), with an error that says what to install."""

from __future__ import annotations

from pathlib import Path

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
