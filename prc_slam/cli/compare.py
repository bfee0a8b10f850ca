"""``prc-slam compare``, ``prc-slam odometry`` and ``prc-slam view``."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import typer

from prc_slam.cli.common import (
    Mode,
    Preset,
    check_outputs,
    class_table,
    console,
    fail,
    finish,
    handles_errors,
    in_progress,
    log,
    print_table,
    print_vehicle_ranges,
    run_config,
    variant_table,
    wrote,
)
from prc_slam.cli.options import (
    LOOPBACK,
    Bind,
    Deskew,
    FrameOptions,
    GrpcPort,
    Json,
    LogEvery,
    MapVoxel,
    MaxFrames,
    PrcPreset,
    ReaderOptions,
    RerunOptions,
    RunConfig,
    SequenceInput,
    ServeSeconds,
    WebPort,
    grouped,
)


def warn_failed(metrics: dict) -> None:
    """One warning per odometry variant that stopped before the last frame (otherwise only
    the JSON's ``failed`` and the table's frame count would tell), and one per variant that gave
    frames too sparse to register the predicted pose; one per untrustworthy variant, and, when no
    variant can be trusted, one line before all of them that says so."""
    total = metrics.get("frames")
    if metrics.get("no_variant_trusted"):
        log.warning("%s", metrics["no_variant_trusted"])
    for name, m in metrics.get("variants", {}).items():
        if m.get("health") == "untrustworthy" and not metrics.get("no_variant_trusted"):
            log.warning("odometry %s is untrustworthy: %s", name, m.get("health_reason"))
        if m.get("coasted_frames"):
            frames = m["coasted_frames"]
            log.warning(
                "odometry %s: %d frame(s) with too few points to register took the predicted pose (frames %s)",
                name,
                len(frames),
                ", ".join(map(str, frames[:10])) + (" ..." if len(frames) > 10 else ""),
            )
        if m.get("failed"):
            of = f" of {total}" if total is not None else ""
            log.warning(
                "odometry %s stopped at frame %s%s: %s; its trajectory holds the %s poses before",
                name,
                m.get("failed_at_frame"),
                of,
                m.get("failure_reason", "failed"),
                m.get("frames"),
            )


def variant_list(text: str) -> list[str]:
    """``--variants``: the comma-separated names, at least one."""
    names = [v.strip() for v in text.split(",") if v.strip()]
    if not names:
        raise ValueError("--variants: give at least one variant (e.g. raw,prc)")
    return names


def odometry_config(preset: Preset, config: Path | None, mode: Mode, deskew: bool) -> Any:
    """The run's config (:func:`prc_slam.cli.common.run_config`), deskewing off with ``--no-deskew``."""
    cfg = run_config(preset, config, mode)
    cfg.odometry.deskew = cfg.odometry.deskew and deskew
    return cfg


def odometry_run(write_partial: Callable[[Any], list[str]], *args: Any, **kwargs: Any) -> Any:
    """:func:`prc_slam.jobs.odometry.run_odometry` under the progress display; on Ctrl-C, the
    frames done written by ``write_partial`` (marked interrupted) and the one line, exit 130."""
    from prc_slam.jobs.odometry import Interrupted, interrupted_line, run_odometry

    try:
        return in_progress(run_odometry, *args, **kwargs)
    except Interrupted as stop:
        raise fail(interrupted_line(stop, write_partial), 130) from None


@handles_errors
@grouped
def compare(
    input: SequenceInput,
    variants: str = typer.Option(
        "raw,prc", help="comma-separated variants: raw, prc, prc+classaware; peers: sor, ror, patchwork"
    ),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban, or forest (trunks for class-aware matching)"),
    deskew: Deskew = True,
    online: bool = typer.Option(False, "--online", help="also run the online car/curb detectors and log them"),
    out: Path = typer.Option(Path("out/compare"), help="output directory"),
    json_path: Path | None = typer.Option(None, "--json", help="also write the metrics JSON (OUT/metrics.json) here"),
    preset: Preset = typer.Option(Preset.multibeam, help="PRC parameters for the prc variant"),
    config: RunConfig = None,
    reader: ReaderOptions = ReaderOptions(),
    frames: FrameOptions = FrameOptions(),
    rerun: RerunOptions = RerunOptions(),
    log_every: LogEvery = 5,
    map_voxel: MapVoxel = 0.5,
    serve_seconds: ServeSeconds = None,
    web_port: WebPort = None,
    grpc_port: GrpcPort = None,
    bind: Bind = LOOPBACK,
    mapclass: bool = typer.Option(False, "--mapclass", help="also classify the run's map (paper 004) vs PRC"),
    mapclass_every: int = typer.Option(5, min=1, help="with --mapclass: accumulate every n-th frame"),
) -> None:
    """Run odometry variants side by side in one process (same KISS-ICP settings) and write
    report.md, metrics.json, trajectories (KITTI and TUM), the config used and plots. With
    ``--online``: the online detectors too, logged beside the clouds. With ``--mapclass``:
    accumulate the map at the PRC variant's poses, classify it after registration and report the
    agreement of PRC labels with it (mapclass.json, report.md)."""
    from prc_slam.jobs.common import write_json
    from prc_slam.jobs.odometry import write_outputs

    check_outputs(out=(out, "dir"), json_path=(json_path, "file"), rrd=(rerun.rrd, "file"))
    names = variant_list(variants)
    if mapclass and frames.stride > 1:
        raise ValueError("--stride: not with --mapclass (the map is accumulated from every frame's index)")
    cfg = odometry_config(preset, config, mode, deskew)
    viewer = rerun.viewer(
        log_every, serve_seconds=serve_seconds, map_voxel=map_voxel, web_port=web_port, grpc_port=grpc_port, bind=bind
    )
    title = f"Odometry comparison on {input}"

    def write(part) -> list[str]:  # an interrupted run: the frames done
        write_outputs(part, cfg, out, title)
        k = part.metrics["interrupted_at_frame"]
        return [str(out / "report.md"), "metrics.json", "config.yaml", f"trajectories ({k} frames)"]

    run, prc_labels = odometry_run(
        write, input, cfg, names, fmt=reader.fmt, max_frames=frames.max_frames, stride=frames.stride, online=online,
        score_prc=True, viewer=viewer, keep_labels_every=mapclass_every if mapclass else None,
        **reader.open_options(),
    )  # fmt: skip
    written = run.written + write_outputs(run, cfg, out, title)
    warn_failed(run.metrics)
    print_table(variant_table(run.metrics, f"odometry on {input}"))
    if run.prc is not None and "per_class" in run.prc:
        print_table(class_table(run.prc, "PRC labels against the reference"))
    if run.online is not None and "per_class" in run.online:
        print_table(class_table(run.online, "online detectors against the reference"))
        print_vehicle_ranges(run.online)
    if mapclass:
        from prc_slam.cli.mapclass import print_mapclass
        from prc_slam.jobs.mapclass import compare_mapclass
        from prc_slam.jobs.report import mapclass_section

        variant = next((v for v in names if v != "raw"), names[0])
        mc = compare_mapclass(
            input, reader.fmt, run, variant, mapclass_every, prc_labels, cfg, out, **reader.open_options()
        )
        console.print(
            f"map: {mc['map_points']:,} points from every {mapclass_every}th frame at the {variant} poses",
            highlight=False,
        )
        written += write_json(out / "mapclass.json", mc)
        with (out / "report.md").open("a") as f:
            f.write(mapclass_section(mc))
        print_mapclass(mc, "map classification")
    finish(written, json_path, run.metrics)


@handles_errors
@grouped
def odometry(
    input: SequenceInput,
    filter: Literal["none", "prc"] = typer.Option("prc", "--filter", help="none: every point; prc: PRC filter"),
    matching: Literal["plain", "class-aware"] = typer.Option(
        "plain", help="plain KISS-ICP, or class-aware (needs --filter prc)"
    ),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban, or forest"),
    deskew: Deskew = True,
    preset: PrcPreset = Preset.multibeam,
    config: RunConfig = None,
    poses_out: Path | None = typer.Option(None, help="write the trajectory here"),
    pose_format: Literal["kitti", "tum"] = typer.Option("kitti", help="trajectory file format"),
    json_path: Json = None,
    reader: ReaderOptions = ReaderOptions(),
    frames: FrameOptions = FrameOptions(),
    rerun: RerunOptions = RerunOptions(),
    log_every: LogEvery = 5,
    bind: Bind = LOOPBACK,
) -> None:
    """KISS-ICP odometry on every frame, on all points or on the PRC-filtered ones."""
    from prc_slam.jobs.common import write_json
    from prc_slam.jobs.odometry import trajectory_file

    if matching == "class-aware" and filter == "none":
        raise ValueError("--matching: class-aware needs PRC labels: use it with --filter prc")
    name = "raw" if filter == "none" else "prc+classaware" if matching == "class-aware" else "prc"
    check_outputs(poses_out=(poses_out, "file"), json_path=(json_path, "file"), rrd=(rerun.rrd, "file"))
    cfg = odometry_config(preset, config, mode, deskew)

    def write(part) -> list[str]:  # an interrupted run: the frames done
        files = [] if poses_out is None else [trajectory_file(part, name, poses_out, pose_format)]
        files += [] if json_path is None else write_json(json_path, part.metrics, cfg)
        return [str(p) for p in files]

    run, _ = odometry_run(
        write, input, cfg, [name], fmt=reader.fmt, max_frames=frames.max_frames, stride=frames.stride,
        viewer=rerun.viewer(log_every, bind=bind), **reader.open_options(),
    )  # fmt: skip
    written = list(run.written)
    warn_failed(run.metrics)
    if poses_out is not None:
        written.append(trajectory_file(run, name, poses_out, pose_format))
    print_table(variant_table(run.metrics, f"odometry on {input}"))
    finish(written, json_path, run.metrics, cfg)


@handles_errors
@grouped
def view(
    input: SequenceInput,
    max_frames: MaxFrames = None,
    reader: ReaderOptions = ReaderOptions(),
    online: bool = typer.Option(True, "--online/--no-online", help="also run and show the online detectors"),
    log_every: LogEvery = 1,
    serve_web: bool = typer.Option(
        False, "--serve-web", help="serve the web viewer instead of spawning the desktop viewer (no display needed)"
    ),
    rrd: Path | None = typer.Option(None, "--rrd", help="write the recording here instead of spawning the viewer"),
    serve_seconds: ServeSeconds = None,
    web_port: WebPort = None,
    grpc_port: GrpcPort = None,
    bind: Bind = LOOPBACK,
) -> None:
    """Spawn the Rerun desktop viewer and watch PRC, the detectors and raw vs PRC-filtered odometry live
    (``--serve-web``: in a browser; ``--rrd FILE``: into a file to open later)."""
    from prc_slam.config import Config
    from prc_slam.jobs.common import Viewer
    from prc_slam.prc.config import PRCConfig

    check_outputs(rrd=(rrd, "file"))
    spawn = not serve_web and rrd is None
    viewer = Viewer(
        rrd, None, serve_web, log_every, spawn=spawn, serve_seconds=serve_seconds, web_port=web_port,
        grpc_port=grpc_port, bind=bind, spawn_name="view",
    )  # fmt: skip
    cfg = Config(prc=PRCConfig.preset("multibeam"))
    run, _ = odometry_run(
        lambda part: [], input, cfg, ["raw", "prc"], fmt=reader.fmt, max_frames=max_frames, online=online,
        viewer=viewer, **reader.open_options(),
    )  # fmt: skip
    wrote(run.written)
