"""``prc-slam [COMMAND] --help`` reads cleanly at any terminal width: no ``<bool>`` for flags
(they take no value), no RST markup (double backticks) from the docstrings, paragraphs wrapped
by the help and not broken where the docstring's lines ended, no word cut in two, every option
listed."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from prc_slam.cli import app

runner = CliRunner()
BOX = re.compile(r"[│╭╮╰╯─┃━┏┓┗┛]")
COMMANDS = sorted(typer.main.get_command(app).commands)


def help_of(command: str | None, columns: int | None) -> str:
    env = {"COLUMNS": str(columns)} if columns else {}
    res = runner.invoke(app, [command, "--help"] if command else ["--help"], env=env)
    assert res.exit_code == 0, res.output
    return res.output


def words(text: str) -> list[str]:
    return BOX.sub(" ", text).split()


def lines_of_a_cell(text: str, start: str) -> list[list[str]]:
    """The lines of each entry of the panel whose title starts with ``start``: an entry starts
    with its name (an option, a command, an argument) near the left border, its further lines
    are indented to its help column."""
    rows: list[list[str]] = []
    inside = False
    for line in text.splitlines():
        if line.startswith("╭─ "):
            inside = line.startswith(f"╭─ {start}")
            continue
        if not inside or not line.startswith("│"):
            continue
        body = line.strip("│").rstrip()
        if len(body) - len(body.lstrip()) <= 4:
            rows.append([body])
        elif rows:
            rows[-1].append(body)
    return rows


@pytest.mark.parametrize("columns", [None, 100])
@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_help_reads_cleanly(command, columns):
    text = help_of(command, columns)
    assert "<bool>" not in text and "``" not in text, text
    wide = set(words(help_of(command, 400)))
    cut = [w for w in words(text) if w not in wide]
    assert not cut, f"words cut at the line's end: {cut}\n{text}"  # every word as at full width
    group = typer.main.get_command(app)
    cmd = group if command is None else group.commands[command]
    for param in cmd.params:
        for opt in [*getattr(param, "opts", []), *getattr(param, "secondary_opts", [])]:
            if opt.startswith("--"):
                assert opt in text, f"{opt} not listed\n{text}"
    assert "--help" in text


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_paragraphs_are_not_broken_where_the_docstring_lines_end(command):
    """On a terminal wide enough, every paragraph of a command's description, its summary in the
    command list and every option's help take one line each: a further line would be a line
    break kept from the docstring (as the command list showed them)."""
    from prc_slam.cli.common import plain_help

    text = help_of(command, 2000)
    for panel in ("Commands", "Options", "Arguments"):
        for row in lines_of_a_cell(text, panel):
            extra = [line for line in row[1:] if "[default:" not in line and "[required]" not in line]
            assert not extra, f"{panel}: {row}"
    group = typer.main.get_command(app)
    doc = (group if command is None else group.commands[command]).help
    description = [line for line in text.split("Usage:")[1].split("╭")[0].splitlines()[1:] if line.strip()]
    assert len(description) == plain_help(doc).count("\n\n") + 1, text
