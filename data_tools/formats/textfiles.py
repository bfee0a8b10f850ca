"""Numeric text tables (pose files, time stamps) read with errors that name the file and the line.

Line numbers in messages are 1-based, as an editor shows them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data_tools.errors import DataError


def read_numeric_table(path: str | Path, columns: int | None, what: str, comments: str = "#") -> np.ndarray:
    """The numbers of a whitespace-separated text file as ``float64[n, columns]``.

    Blank lines and lines starting with ``comments`` are skipped. A line with the wrong number of
    values, a value that is not a number, or a non-finite value raises :class:`DataError` naming
    ``path``, the 1-based line and what was expected (``what``, e.g. ``"KITTI poses (3x4
    row-major)"``).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read {what}: {exc}") from exc
    rows: list[list[float]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith(comments):
            continue
        fields = stripped.split()
        if columns is not None and len(fields) != columns:
            raise DataError(f"{path}: line {number}: {len(fields)} values, expected {columns} ({what})")
        try:
            values = [float(v) for v in fields]
        except ValueError as exc:
            raise DataError(f"{path}: line {number}: not a number ({exc}); expected {what}") from exc
        if not np.isfinite(values).all():
            raise DataError(f"{path}: line {number}: non-finite value in {what}")
        rows.append(values)
    if not rows:
        return np.zeros((0, columns or 0))
    width = len(rows[0])
    if columns is None and any(len(r) != width for r in rows):
        bad = next(i for i, r in enumerate(rows) if len(r) != width)
        raise DataError(f"{path}: rows of different lengths (row {bad + 1} of the data); expected {what}")
    return np.asarray(rows, dtype=np.float64)
