"""``prc-slam live``."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from prc_slam.cli.common import Preset, check_outputs, console, finish, handles_errors, run_config
from prc_slam.cli.options import (
    Format,
    Json,
    LogEvery,
    Meta,
    Model,
    PrcPreset,
    RunConfig,
    ServedRerunOptions,
    grouped,
)


def summary_line(m: dict) -> str:
    """One line of the run's figures."""
    lat = m["latency_ms"]
    fmt = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    return (
        f"live: {m['frames']} sweeps out of {m['sweeps_in']} in, {m['dropped_frames']} dropped, "
        f"{m['lost_packets']} packets lost, {m['foreign_packets']} foreign; latency p50 {fmt(lat['p50'])} ms, "
        f"p99 {fmt(lat['p99'])} ms, max {fmt(lat['max'])} ms; in {fmt(m['rate_hz_in'])} Hz, "
        f"out {fmt(m['rate_hz_out'])} Hz ({m['ended_by']})"
    )


@handles_errors
@grouped
def live(
    source: str = typer.Argument(
        ..., help="velodyne://HOST:PORT (2368), ouster://HOST:PORT (7502, with --meta), or a recording (--realtime)"
    ),
    variant: Literal["raw", "prc", "prc+classaware"] = typer.Option(
        "prc", "--variant", help="the odometry variant run"
    ),
    online: bool = typer.Option(False, "--online", help="also run the online car/curb detectors"),
    realtime: bool = typer.Option(
        False, "--realtime", help="a recording as SOURCE: play it at its recorded rate as a stand-in sensor"
    ),
    rate: float = typer.Option(1.0, "--rate", min=0.01, help="with --realtime: speed factor"),
    timeout: float | None = typer.Option(
        None, "--timeout", min=0.1, help="end the run after this long without packets"
    ),
    queue: int = typer.Option(1, "--queue", min=1, help="sweeps waiting at most; when full the oldest is dropped"),
    max_frames: int | None = typer.Option(None, "--max-frames", min=1, help="end after this many sweeps"),
    preset: PrcPreset = Preset.multibeam,
    config: RunConfig = None,
    meta: Meta = None,
    model: Model = None,
    fmt: Format = None,
    rerun: ServedRerunOptions = ServedRerunOptions(),
    spawn: bool = typer.Option(False, "--spawn", help="spawn the Rerun desktop viewer and watch live"),
    log_every: LogEvery = 5,
    out: Path | None = typer.Option(None, "--out", help="write the filtered stream here (.mcap), as the run goes"),
    poses_out: Path | None = typer.Option(None, "--poses-out", help="write the poses here (TUM), as the run goes"),
    labels_out: Path | None = typer.Option(
        None, "--labels-out", help="write each sweep's PRC labels here (NNNNNN.label, as classify does)"
    ),
    json_path: Json = None,
) -> None:
    """Run PRC, the filter and KISS-ICP on a sensor's sweeps as they arrive, and watch them live.

    Receiving runs in its own process (Velodyne; a thread for Ouster and recordings) and never
    waits; when processing falls behind, whole sweeps are dropped and counted (``--queue``). A
    status line (rates, drops, latency) every second on a terminal, every 10 s in the log; the
    figures at the end and in --json. Ctrl-C or SIGTERM stops the run and closes every output."""
    from prc_slam.live.run import LiveOptions, run_live
    from prc_slam.live.sources import parse_source

    src = parse_source(source)
    if src.kind == "file" and not realtime:
        raise ValueError(f"SOURCE {source}: a recording is played live only with --realtime")
    if src.kind == "ouster" and meta is None:
        raise ValueError("--meta: ouster:// needs the sensor's metadata json (--meta sensor.json)")
    if out is not None and out.suffix.lower() != ".mcap":
        raise ValueError(f"--out {out}: the filtered stream is written as MCAP: give a .mcap name")
    check_outputs(
        rrd=(rerun.rrd, "file"), out=(out, "file"), poses_out=(poses_out, "file"), json_path=(json_path, "file"),
        labels_out=(labels_out, "dir"),
    )  # fmt: skip
    cfg = run_config(preset, config)
    opts = LiveOptions(
        variant=variant, online=online, timeout=timeout, queue=queue, realtime_rate=rate,
        max_frames=max_frames, model=model, meta=meta, fmt=fmt,
        open_options={"meta": meta} if (src.kind == "file" and meta is not None) else {},
    )  # fmt: skip
    viewer = rerun.viewer(log_every, spawn=spawn)
    run = run_live(src, cfg, opts, viewer=viewer, poses_out=poses_out, filtered_out=out, labels_out=labels_out)
    console.print(summary_line(run.metrics), highlight=False)
    finish(list(run.written), json_path, run.metrics, cfg)
