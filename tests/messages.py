"""Checks on the text of errors: one line, naming the input."""

from __future__ import annotations

from pathlib import Path

import pytest


def one_line(exc: pytest.ExceptionInfo, path: Path) -> str:
    """The error's message, checked to be one line that names ``path``."""
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg, msg
    return msg
