"""``prc-slam bench``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from prc_slam.cli.common import DEFAULT_KITTI, check_outputs, console, finish, handles_errors, print_table
from prc_slam.cli.options import Json


@handles_errors
def bench(
    kitti: Path = typer.Option(DEFAULT_KITTI, help="KITTI directory for the real-data figures (skipped if absent)"),
    json_path: Json = None,
) -> None:
    """Throughput of each stage on its reference input (single process)."""
    from prc_slam.jobs.bench import run_bench

    check_outputs(json_path=(json_path, "file"))
    if not (kitti / "velodyne").is_dir():
        console.print(f"[yellow]{kitti} not found: KITTI figures skipped[/yellow]")
    results = run_bench(kitti if (kitti / "velodyne").is_dir() else None)
    table = Table(title="prc-slam bench")
    table.add_column("stage")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for stage, figures in results.items():
        for key, value in figures.items():
            table.add_row(stage, key, f"{value:,.3f}" if isinstance(value, float) else str(value))
    print_table(table)
    finish([], json_path, results)
