"""``prc-slam batch``."""

from __future__ import annotations

from pathlib import Path

import typer

from prc_slam.cli.common import check_outputs, console, handles_errors, say, wrote
from prc_slam.cli.options import LOOPBACK, Bind


@handles_errors
def batch(
    plan: Path = typer.Argument(..., help="plan YAML: 'inputs' (paths, globs) and the 'job' per input"),
    out: Path = typer.Option(Path("out/batch"), help="output directory: OUT/<input-name>/ per input, summary.*"),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Dask scheduler (tcp://HOST:8786; default $DASK_SCHEDULER_ADDRESS, else local)"
    ),
    workers: int | None = typer.Option(
        None, "--workers", min=1, help="local cluster: worker processes (default: one per CPU)"
    ),
    retries: int = typer.Option(2, "--retries", min=0, help="retries of a task that raised an unexpected error"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace the results of an earlier batch in OUT"),
    bind: Bind = LOOPBACK,
) -> None:
    """Run a plan's job on every input, one Dask task per input (a local cluster of worker
    processes by default; --scheduler for a real cluster); writes OUT/<input-name>/ as the
    single-input command would, plus OUT/summary.md, summary.json and summary.png."""
    from prc_slam.jobs.batch import load_plan, prepare_out, resolve_tasks, run_batch
    from prc_slam.jobs.distributed import open_client
    from prc_slam.jobs.progress import progress

    check_outputs(out=(out, "dir"))
    spec = load_plan(plan)
    tasks = resolve_tasks(spec, plan.resolve().parent)
    say(f"{len(tasks)} inputs: " + ", ".join(f"{t.name} ({t.kind})" for t in tasks))
    prepare_out(out, tasks, overwrite)  # refuse (or clear) earlier results before starting a cluster
    with open_client(scheduler, workers, note=say, bind=bind) as client, progress() as reporter:
        summary = run_batch(tasks, out, client, reporter=reporter, note=say, retries=retries, overwrite=overwrite)
    ok = summary["inputs"] - summary["failed"]
    console.print(
        f"{ok} of {summary['inputs']} inputs done in {summary['wall_seconds']:.1f} s on {summary['workers']} workers",
        highlight=False,
    )
    wrote([out / "summary.md", out / "summary.json", out / "summary.png"])
    if summary["failed"]:
        for r in summary["rows"]:
            if r["status"] != "ok":
                console.print(f"[red]failed:[/red] {r['name']}: {r.get('error')}", highlight=False)
        raise typer.Exit(1)
