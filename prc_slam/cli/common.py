"""What every command shares: the console, the one error path, output checks, option types, the
progress display, the JSON and ``wrote`` lines at the end, tables (the shared options:
:mod:`prc_slam.cli.options`)."""

from __future__ import annotations

import functools
import inspect
import logging
import re
import sys
from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import Any, TypeVar

import typer
from rich.console import Console
from rich.table import Table

try:  # typer >= 0.2x carries its own copy of click
    from typer._click import exceptions as _click
except ImportError:  # pragma: no cover - older typer on click
    from click import exceptions as _click

console = Console(stderr=True, soft_wrap=True)
log = logging.getLogger("prc_slam")
DEFAULT_KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti00"

F = TypeVar("F", bound=Callable[..., Any])


class Mode(str, Enum):
    urban = "urban"
    forest = "forest"


class Preset(str, Enum):
    paper = "paper"
    multibeam = "multibeam"


def one_line(exc: BaseException) -> str:
    """An exception as one line naming the option or file: pydantic validation errors name the
    option (``--speed: ...``), everything else is its message's first line."""
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        parts = []
        for err in exc.errors():
            loc = ".".join(str(p) for p in err.get("loc", ()))
            name = "--" + loc.replace("_", "-") if loc else "config"
            parts.append(
                f"{name}: {err.get('msg', 'invalid')}" + (f" (got {err['input']!r})" if "input" in err else "")
            )
        return "; ".join(parts)
    text = str(exc).strip() or type(exc).__name__
    return " ".join(text.split("\n")[0].split())


_reported: list[str] = []  # the error lines printed in this process


def fail(message: str, code: int = 2) -> typer.Exit:
    console.print(f"[red]error:[/red] {message}", markup=True, highlight=False)
    _reported.append(message)
    return typer.Exit(code=code)


def flag_of(name: str) -> str:
    """The option of a parameter name: ``json_path`` → ``--json``, ``labels_out`` → ``--labels-out``."""
    return "--" + name.removesuffix("_path").replace("_", "-")


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except OSError:  # e.g. a directory on the way that may not be searched
        return False


def unwritable(path: Path, kind: str) -> str | None:
    """Why ``path`` cannot be written as ``kind`` (``file``, ``dir`` or ``any``), or None.

    Asks the file system itself, not the permission bits (which say yes to root everywhere,
    also in ``/proc``): an existing file is opened for appending (nothing written), otherwise a
    file is created and removed in the nearest existing directory on the way."""
    import tempfile

    if kind == "dir" and _exists(path) and not path.is_dir():
        return "it is a file; a directory is needed"
    if kind == "file" and path.is_dir():
        return "it is a directory; a file name is needed"
    if kind == "file" and _exists(path):
        try:
            with path.open("ab"):
                return None
        except OSError as exc:
            return exc.strerror or str(exc)
    folder = path if kind != "file" and path.is_dir() else path.parent
    while not _exists(folder) and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        return f"{folder} is a file, not a directory"
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".prc-slam-check-"):
            return None
    except OSError as exc:
        return f"{exc.strerror or exc} (creating a file in {folder})"


def check_output(flag: str, path: Path | None, kind: str = "file") -> None:
    """Raise the one-line error ``--flag: cannot write PATH: <reason>`` (exit 2) unless ``path``
    (None: not asked for) can be written as ``kind`` (:func:`unwritable`)."""
    if path is None:
        return
    reason = unwritable(Path(path), kind)
    if reason is not None:
        raise fail(f"{flag}: cannot write {path}: {reason}")


def check_outputs(**outputs: tuple[Path | None, str]) -> None:
    """Check the output paths before any work, so that a long run does not fail at its end.

    ``outputs`` maps a parameter name (``labels_out``, shown as ``--labels-out``; ``json_path``
    as ``--json``) to ``(path, kind)``, kind ``dir`` (a directory, created later), ``file`` or
    ``any``. Raises the one-line error naming the option (:func:`check_output`) when the path is
    a file where a directory is needed (or the reverse), when an existing part of its path is a
    file, or when nothing can be created where it would go."""
    for name, (path, kind) in outputs.items():
        check_output(flag_of(name), path, kind)


def _user_errors() -> tuple[type[BaseException], ...]:
    from pydantic import ValidationError

    from data_tools.errors import DataError
    from prc_slam.pipeline import FrameError
    from prc_slam.scan import ScanError

    return (DataError, ScanError, FrameError, ValueError, ValidationError, OSError)


def interrupted_by_user(exc: BaseException) -> bool:
    """True for Ctrl-C, also when a C extension turned it into another error (e.g. Open3D's
    ``ImportError: initialization failed`` when interrupted while loading)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt | typer.Abort):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def handles_errors(fn: F) -> F:
    """The one error path of every command: a user error (bad file, bad option, malformed data)
    → ``error: <option or file>: <problem>``, exit 2; Ctrl-C → ``interrupted``, exit 130."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except typer.Exit:
            raise
        except BaseException as exc:
            if interrupted_by_user(exc):
                raise fail("interrupted", 130) from None
            if isinstance(exc, _user_errors()):
                raise fail(one_line(exc)) from None
            raise

    return wrapper  # type: ignore[return-value]


def plain_help(text: str | None) -> str | None:
    """A docstring as help text: its paragraphs each on one line (the help wraps them to the
    terminal; a docstring's own line breaks would stay in the command list), RST literals
    (````--online````) as plain text."""
    if not text:
        return text
    paragraphs = [" ".join(p.split()) for p in inspect.cleandoc(text).split("\n\n")]
    return re.sub(r"``(.+?)``", r"\1", "\n\n".join(p for p in paragraphs if p))


def value_label(param: Any, ctx: Any) -> str | None:
    """What an option's value is, as the help shows it: nothing for a flag (typer's ``<bool>``:
    a flag takes no value), choices with spaces between them so that a narrow help can wrap
    them (``<auto | ring | order | beams>``), ``<int>`` for a number in a range (the range is
    shown beside it), else typer's own label."""
    if getattr(param, "is_flag", False):
        return ""
    display = getattr(param, "display_type", None)
    if param.metavar is not None or display is None:
        return param.metavar
    label = display(ctx)
    if "|" in label:
        return " | ".join(label.split("|"))
    return label.replace(" range>", ">")


def tidy_help(command: Any, ctx: Any) -> Any:
    """``command`` with :func:`plain_help` texts and :func:`value_label` labels."""
    command.help = plain_help(command.help)
    command.short_help = plain_help(command.short_help)
    for param in command.get_params(ctx):
        if getattr(param, "help", None):
            param.help = plain_help(param.help)
        if getattr(param, "param_type_name", "") == "option":  # (an argument's metavar is its name)
            param.metavar = value_label(param, ctx)
    return command


class OneLineGroup(typer.core.TyperGroup):
    """Usage errors (unknown option, value out of range) as one line, exit 2; Ctrl-C exit 130;
    help texts tidied (:func:`tidy_help`)."""

    def get_command(self, ctx, cmd_name):  # type: ignore[override]
        command = super().get_command(ctx, cmd_name)
        return None if command is None else tidy_help(command, ctx)

    def format_help(self, ctx, formatter):  # type: ignore[override]
        tidy_help(self, ctx)
        return super().format_help(ctx, formatter)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):  # type: ignore[override]
        _reported.clear()
        try:
            rv = super().main(args=args, prog_name=prog_name, complete_var=complete_var, standalone_mode=False, **extra)
        except _click.NoArgsIsHelpError:  # the help is already printed
            rv = 0
        except _click.UsageError as exc:
            param = getattr(exc, "param", None)
            message = exc.format_message()
            if param is not None and getattr(param, "opts", None) and param.opts[0] not in message:
                message = f"{param.opts[0]}: {message}"
            console.print(f"[red]error:[/red] {message}", highlight=False)
            rv = 2
        except _click.ClickException as exc:
            console.print(f"[red]error:[/red] {exc.format_message()}", highlight=False)
            rv = exc.exit_code
        except (typer.Abort, KeyboardInterrupt):
            rv = 130
        if rv == 130 and not _reported:  # Ctrl-C outside a command (typer turns it into exit 130)
            fail("interrupted", 130)
        if standalone_mode:
            sys.exit(rv or 0)
        return rv


class ConsoleHandler(logging.Handler):
    """Log records as plain, unwrapped lines on standard error (``warning: ...`` for warnings)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            if record.levelno >= logging.WARNING:
                text = f"{record.levelname.lower()}: {text}"
            console.print(text, markup=False, highlight=False, soft_wrap=True)
        except Exception:  # pragma: no cover - logging must never raise
            self.handleError(record)


def setup_logging(log_file: Path | None, quiet: bool) -> None:
    """Warnings and progress lines on standard error (always), everything at INFO in ``log_file``."""
    root = logging.getLogger("prc_slam")
    for h in list(root.handlers):
        root.removeHandler(h)
    root.setLevel(logging.INFO)
    root.propagate = False
    handler = ConsoleHandler()
    handler.setLevel(logging.WARNING if quiet else logging.INFO)
    root.addHandler(handler)
    if log_file is not None:
        check_outputs(log_file=(log_file, "file"))
        try:
            log_file.parent.mkdir(parents=True, exist_ok=True)
            fh = logging.FileHandler(log_file)
        except OSError as exc:
            raise fail(f"--log-file {log_file}: {exc.strerror or exc}") from None
        fh.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        root.addHandler(fh)


def say(message: str) -> None:
    """A line for the user (standard error, and the log file)."""
    log.info(message)


def print_table(table: Table) -> None:
    """Print a table on standard output, never truncated: full width off a terminal, folded cells on one."""
    out = Console()
    if not out.is_terminal:
        out = Console(width=max(200, out.width))
    for col in table.columns:
        col.overflow = "fold"
        col.no_wrap = False
    out.print(table)


def class_table(metrics: dict[str, Any], title: str) -> Table:
    """Per-class precision / recall / F1; a class the method never outputs is said so, with no
    scores (:func:`prc_slam.jobs.report.class_rows`)."""
    from prc_slam.jobs.report import class_rows

    table = Table(title=title)
    for col in ("class", "support", "precision", "recall", "f1"):
        table.add_column(col, justify="right" if col != "class" else "left")

    def fmt(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    for name, support, *scores in class_rows(metrics.get("per_class", {}), fmt):
        table.add_row(name, str(support), *scores)
    return table


def variant_table(metrics: dict[str, Any], title: str) -> Table:
    """The odometry variants' figures; a missing KITTI drift says why (:func:`prc_slam.jobs.report.variant_cell`)."""
    from prc_slam.jobs.report import FIELDS, variant_cell

    variants = metrics["variants"]
    fields = [f for f in FIELDS if any(f in m for m in variants.values())]
    table = Table(title=title)
    table.add_column("variant")
    for f in fields:
        table.add_column(f, justify="right")
    for name, m in variants.items():
        table.add_row(name, *(variant_cell(m, f) for f in fields))
    return table


def print_vehicle_ranges(metrics: dict[str, Any]) -> None:
    """The vehicle instances and points found by range, when the run scored them."""
    if "vehicle_by_range" in metrics:
        from prc_slam.evaluation.scoring import range_table

        print_table(range_table(metrics["vehicle_by_range"], "vehicle instances and points by range"))


def prc_config(mode: Mode, preset: Preset, adaptive: bool | None, config_path: Path | None):
    from prc_slam.config import Config
    from prc_slam.prc.config import PRCConfig

    if config_path is not None:
        cfg = Config.from_yaml(config_path).prc
        return cfg if adaptive is None else cfg.model_copy(update={"adaptive": adaptive})
    return PRCConfig.named(preset.value, mode.value, adaptive)


def run_config(preset: Preset, config_path: Path | None, mode: Mode = Mode.urban):
    from prc_slam.config import Config
    from prc_slam.odometry.classaware import ClassAwareConfig

    base = Config(prc=prc_config(mode, preset, None, None), classaware=ClassAwareConfig.for_mode(mode.value))
    return base if config_path is None else Config.from_yaml(config_path, base)


def in_progress(job: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``job(*args, reporter=..., **kwargs)`` under the progress display (standard error)."""
    from prc_slam.jobs.progress import progress

    with progress() as reporter:
        return job(*args, reporter=reporter, **kwargs)


def finish(written: list, json_path: Path | None, metrics: dict[str, Any], config: Any = None) -> None:
    """Write the metrics JSON when ``--json`` asks for it (and the config used beside it, when
    given), then say every file written."""
    from prc_slam.jobs.common import write_json

    wrote(written if json_path is None else [*written, *write_json(json_path, metrics, config)])


def wrote(paths) -> None:
    """One line ``wrote PATH`` per file written (None: nothing)."""
    for p in paths:
        if p is not None:
            console.print(f"wrote {p}", highlight=False)
