"""``prc-slam``: the command-line interface (typer), one module per command.

Commands only parse options and call the library (:mod:`prc_slam.jobs`); every user error takes
one path (:func:`prc_slam.cli.common.handles_errors`); the console entry point is
:func:`prc_slam.__main__.main`: one line ``error: <option or file>:
<problem>`` and exit 2; Ctrl-C exits 130 with one line.
"""

from __future__ import annotations

from pathlib import Path

import typer

from prc_slam.cli import batch, bench, classify, compare, demo, live, mapclass, replay, simulate
from prc_slam.cli import filter as filter_cmd
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


for _command in (classify.classify, classify.detect, compare.compare, compare.odometry, compare.view):
    app.command()(_command)
app.command(name="filter")(filter_cmd.filter_stream)
for _command in (mapclass.mapclass, simulate.simulate, bench.bench, demo.demo, batch.batch, live.live, replay.replay):
    app.command()(_command)


__all__ = ["app"]
