"""``prc-slam``: the command-line interface (typer), one module per command.

Commands only parse options and call the library (:mod:`prc_slam.jobs`); every user error takes
one path (:func:`prc_slam.cli.common.handles_errors`): one line ``error: <option or file>:
<problem>`` and exit 2; Ctrl-C exits 130 with one line.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import typer

from prc_slam.cli import bench, classify, compare, demo, mapclass, simulate
from prc_slam.cli.common import OneLineGroup, setup_logging

app = typer.Typer(
    cls=OneLineGroup,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    help="Preregistration classification for LiDAR odometry.",
)


@app.callback()
def _options(
    log_file: Path | None = typer.Option(None, "--log-file", help="also write progress and warnings to this file"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="only warnings and errors on standard error"),
) -> None:
    setup_logging(log_file, quiet)


for _module in (classify, compare, mapclass, simulate, bench, demo):
    _module.register(app)

try:  # the filtered stream writer lands with the readers
    from prc_slam.cli import filter as _filter

    _filter.register(app)
except ImportError:  # pragma: no cover
    pass


def main() -> None:
    """Console entry point: the app, and an immediate exit on Ctrl-C (no interpreter tear-down
    messages from half-loaded extensions)."""
    try:
        app()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if code == 130:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(130)
        raise
    except KeyboardInterrupt:
        sys.stderr.write("error: interrupted\n")
        sys.stderr.flush()
        os._exit(130)


__all__ = ["app", "main"]
