"""``prc-slam demo``: the main job on an embedded default (a simulated urban drive)."""

from __future__ import annotations

from pathlib import Path

import typer

from prc_slam.cli.common import check_output, class_table, console, handles_errors, print_table, variant_table
from prc_slam.cli.options import LOOPBACK, Bind, Connect, LogEvery, MapVoxel, ServeWeb


@handles_errors
def demo(
    out: Path = typer.Option(Path("out/demo"), help="output directory"),
    frames: int = typer.Option(150, min=2, help="frames of the simulated hdl64 urban drive"),
    seed: int = typer.Option(0, min=0, help="scene and noise seed"),
    connect: Connect = None,
    serve_web: ServeWeb = False,
    bind: Bind = LOOPBACK,
    log_every: LogEvery = 5,
    map_voxel: MapVoxel = 0.5,
) -> None:
    """Simulate an urban drive (cached after the first run), run PRC, the online car/curb
    detectors and raw vs PRC-filtered KISS-ICP odometry in one pass, and write a report, metrics,
    trajectories, plots and a Rerun recording."""
    from prc_slam.config import Config
    from prc_slam.jobs.common import Viewer, write_json
    from prc_slam.jobs.demo import simulated_drive
    from prc_slam.jobs.odometry import run_odometry, write_outputs
    from prc_slam.jobs.progress import progress
    from prc_slam.prc.config import PRCConfig

    rrd = out.with_suffix(".rrd")
    check_output("--out", out, "dir")
    check_output("--out", rrd, "file")  # the recording beside OUT
    cfg = Config(prc=PRCConfig.preset("multibeam"))
    with progress() as reporter:
        root, cached = simulated_drive(out, frames, seed, reporter)
        viewer = Viewer(rrd, connect, serve_web, log_every, map_voxel=map_voxel, bind=bind)
        run, _ = run_odometry(root, cfg, ["raw", "prc"], online=True, score_prc=True, viewer=viewer, reporter=reporter)
    console.print(f"simulated drive: {root}" + (" (cached)" if cached else ""), highlight=False)
    written = write_outputs(run, cfg, out, f"Raw vs PRC-filtered KISS-ICP on {root.name}")
    if run.prc is not None:
        written += write_json(out / "prc_metrics.json", run.prc)
        if "per_class" in run.prc:
            print_table(class_table(run.prc, "PRC (multibeam setting) on the simulated urban drive, 1 % outliers"))
    if run.online is not None:
        written += write_json(out / "online_metrics.json", run.online)
    print_table(variant_table(run.metrics, "KISS-ICP: raw vs PRC-filtered"))
    console.print("outputs:", highlight=False)
    for p in [*written, *run.written]:
        console.print(f"  {p}", highlight=False)
    if run.written:
        console.print(f"open the recording with: .venv/bin/rerun {run.written[0]}", highlight=False)
