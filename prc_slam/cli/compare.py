"""``prc-slam compare``, ``prc-slam odometry`` and ``prc-slam view``."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer

from prc_slam.cli.common import (
    BIND_OPT,
    COLS_OPT,
    CONNECT_OPT,
    EVERY_OPT,
    FORMAT_OPT,
    GRPC_PORT_OPT,
    JSON_OPT,
    MAP_VOXEL_OPT,
    MAX_FRAMES_OPT,
    META_OPT,
    MODEL_OPT,
    ORGANIZE_OPT,
    ROWS_OPT,
    RRD_OPT,
    SERVE_OPT,
    SERVE_SECONDS_OPT,
    STRIDE_OPT,
    TOPIC_OPT,
    WEB_PORT_OPT,
    Mode,
    OrganizeMethod,
    Preset,
    check_outputs,
    class_table,
    console,
    fail,
    handles_errors,
    input_options,
    log,
    print_table,
    run_config,
    variant_list,
    variant_table,
    wrote,
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


def register(app: typer.Typer) -> None:
    app.command()(compare)
    app.command()(odometry)
    app.command()(view)


class FilterMode(str, Enum):
    none = "none"
    prc = "prc"


class Matching(str, Enum):
    plain = "plain"
    class_aware = "class-aware"


class PoseFormat(str, Enum):
    kitti = "kitti"
    tum = "tum"


@handles_errors
def compare(
    input: Path = typer.Argument(..., help="any supported input (KITTI, simulated, Ouster, bag, MCAP, PCD folder)"),
    variants: str = typer.Option(
        "raw,prc", help="comma-separated variants: raw, prc, prc+classaware; peers: sor, ror, patchwork"
    ),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban, or forest (trunks for class-aware matching)"),
    deskew: bool = typer.Option(True, "--deskew/--no-deskew", help="KISS-ICP's constant-velocity deskewing"),
    online: bool = typer.Option(False, "--online", help="also run the online car/curb detectors and log them"),
    out: Path = typer.Option(Path("out/compare"), help="output directory"),
    json_path: Path | None = typer.Option(None, "--json", help="also write the metrics JSON (OUT/metrics.json) here"),
    preset: Preset = typer.Option(Preset.multibeam, help="PRC parameters for the prc variant"),
    config: Path | None = typer.Option(None, help="YAML config (prc, filter, odometry sections)"),
    topic: str | None = TOPIC_OPT,
    meta: Path | None = META_OPT,
    model: str | None = MODEL_OPT,
    rows: int | None = ROWS_OPT,
    cols: int | None = COLS_OPT,
    organize: OrganizeMethod | None = ORGANIZE_OPT,
    fmt: str | None = FORMAT_OPT,
    max_frames: int | None = MAX_FRAMES_OPT,
    stride: int = STRIDE_OPT,
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    log_every: int = EVERY_OPT,
    map_voxel: float = MAP_VOXEL_OPT,
    serve_seconds: float | None = SERVE_SECONDS_OPT,
    web_port: int | None = WEB_PORT_OPT,
    grpc_port: int | None = GRPC_PORT_OPT,
    bind: str = BIND_OPT,
    mapclass: bool = typer.Option(False, "--mapclass", help="also classify the run's map (paper 004) vs PRC"),
    mapclass_every: int = typer.Option(5, min=1, help="with --mapclass: accumulate every n-th frame"),
) -> None:
    """Run odometry variants side by side in one process (same KISS-ICP settings) and write
    report.md, metrics.json, trajectories (KITTI and TUM), the config used and plots. With
    ``--online``: the online detectors too, logged beside the clouds. With ``--mapclass``:
    accumulate the map at the PRC variant's poses, classify it after registration and report the
    agreement of PRC labels with it (mapclass.json, report.md)."""
    from prc_slam.jobs.common import Viewer, write_json
    from prc_slam.jobs.odometry import Interrupted, interrupted_line, run_odometry, write_outputs
    from prc_slam.jobs.progress import progress

    check_outputs(out=(out, "dir"), json_path=(json_path, "file"), rrd=(rrd, "file"))
    names = variant_list(variants)
    if mapclass and stride > 1:
        raise ValueError("--stride: not with --mapclass (the map is accumulated from every frame's index)")
    cfg = run_config(preset, config, mode)
    cfg.odometry.deskew = cfg.odometry.deskew and deskew
    viewer = Viewer(
        rrd, connect, serve_web, log_every, serve_seconds=serve_seconds, map_voxel=map_voxel, web_port=web_port,
        grpc_port=grpc_port, bind=bind,
    )  # fmt: skip
    title = f"Odometry comparison on {input}"
    try:
        with progress() as reporter:
            run, prc_labels = run_odometry(
                input, cfg, names, fmt=fmt, max_frames=max_frames, stride=stride, online=online, score_prc=True,
                viewer=viewer,
                reporter=reporter, keep_labels_every=mapclass_every if mapclass else None,
                **input_options(topic, meta, model, rows, cols, organize=organize),
            )  # fmt: skip
    except Interrupted as stop:  # the frames done are written, marked interrupted

        def write(part) -> list[str]:
            write_outputs(part, cfg, out, title)
            k = part.metrics["interrupted_at_frame"]
            return [str(out / "report.md"), "metrics.json", "config.yaml", f"trajectories ({k} frames)"]

        raise fail(interrupted_line(stop, write), 130) from None
    written = run.written + write_outputs(run, cfg, out, title)
    warn_failed(run.metrics)
    print_table(variant_table(run.metrics, f"odometry on {input}"))
    if run.prc is not None and "per_class" in run.prc:
        print_table(class_table(run.prc, "PRC labels against the reference"))
    if run.online is not None and "per_class" in run.online:
        print_table(class_table(run.online, "online detectors against the reference"))
        if "vehicle_by_range" in run.online:
            from prc_slam.evaluation.scoring import range_table

            print_table(range_table(run.online["vehicle_by_range"], "vehicle instances and points by range"))
    if mapclass:
        from prc_slam.cli.mapclass import print_mapclass
        from prc_slam.jobs.mapclass import compare_mapclass
        from prc_slam.jobs.report import mapclass_section

        variant = next((v for v in names if v != "raw"), names[0])
        opts = input_options(topic, meta, model, rows, cols, organize=organize)
        mc = compare_mapclass(input, fmt, run, variant, mapclass_every, prc_labels, cfg, out, **opts)
        console.print(
            f"map: {mc['map_points']:,} points from every {mapclass_every}th frame at the {variant} poses",
            highlight=False,
        )
        written += write_json(out / "mapclass.json", mc)
        with (out / "report.md").open("a") as f:
            f.write(mapclass_section(mc))
        print_mapclass(mc, "map classification")
    if json_path is not None:
        written += write_json(json_path, run.metrics)
    wrote(written)


@handles_errors
def odometry(
    input: Path = typer.Argument(..., help="any supported input (KITTI, simulated, Ouster, bag, MCAP, PCD folder)"),
    filter: FilterMode = typer.Option(FilterMode.prc, "--filter", help="none: every point; prc: PRC filter"),
    matching: Matching = typer.Option(Matching.plain, help="plain KISS-ICP, or class-aware (needs --filter prc)"),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban, or forest"),
    deskew: bool = typer.Option(True, "--deskew/--no-deskew", help="KISS-ICP's constant-velocity deskewing"),
    preset: Preset = typer.Option(Preset.multibeam, help="PRC parameters"),
    config: Path | None = typer.Option(None, help="YAML config (prc, filter, odometry sections)"),
    poses_out: Path | None = typer.Option(None, help="write the trajectory here"),
    pose_format: PoseFormat = typer.Option(PoseFormat.kitti, help="trajectory file format"),
    json_path: Path | None = JSON_OPT,
    topic: str | None = TOPIC_OPT,
    meta: Path | None = META_OPT,
    model: str | None = MODEL_OPT,
    rows: int | None = ROWS_OPT,
    cols: int | None = COLS_OPT,
    organize: OrganizeMethod | None = ORGANIZE_OPT,
    fmt: str | None = FORMAT_OPT,
    max_frames: int | None = MAX_FRAMES_OPT,
    stride: int = STRIDE_OPT,
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    log_every: int = EVERY_OPT,
    bind: str = BIND_OPT,
) -> None:
    """KISS-ICP odometry on every frame, on all points or on the PRC-filtered ones."""
    from prc_slam.jobs.common import Viewer, write_json
    from prc_slam.jobs.odometry import Interrupted, interrupted_line, run_odometry, trajectory_file
    from prc_slam.jobs.progress import progress

    if matching is Matching.class_aware and filter is FilterMode.none:
        raise ValueError("--matching: class-aware needs PRC labels: use it with --filter prc")
    name = "raw" if filter is FilterMode.none else "prc+classaware" if matching is Matching.class_aware else "prc"
    check_outputs(poses_out=(poses_out, "file"), json_path=(json_path, "file"), rrd=(rrd, "file"))
    cfg = run_config(preset, config, mode)
    cfg.odometry.deskew = cfg.odometry.deskew and deskew
    try:
        with progress() as reporter:
            run, _ = run_odometry(
                input, cfg, [name], fmt=fmt, max_frames=max_frames, stride=stride,
                viewer=Viewer(rrd, connect, serve_web, log_every, bind=bind),
                reporter=reporter, **input_options(topic, meta, model, rows, cols, organize=organize),
            )  # fmt: skip
    except Interrupted as stop:  # the frames done are written, marked interrupted

        def write(part) -> list[str]:
            files = [] if poses_out is None else [trajectory_file(part, name, poses_out, pose_format.value)]
            files += [] if json_path is None else write_json(json_path, part.metrics, cfg)
            return [str(p) for p in files]

        raise fail(interrupted_line(stop, write), 130) from None
    written = list(run.written)
    warn_failed(run.metrics)
    if poses_out is not None:
        written.append(trajectory_file(run, name, poses_out, pose_format.value))
    print_table(variant_table(run.metrics, f"odometry on {input}"))
    if json_path is not None:
        written += write_json(json_path, run.metrics, cfg)
    wrote(written)


@handles_errors
def view(
    input: Path = typer.Argument(..., help="any supported input (KITTI, simulated, Ouster, bag, MCAP, PCD folder)"),
    max_frames: int | None = MAX_FRAMES_OPT,
    topic: str | None = TOPIC_OPT,
    meta: Path | None = META_OPT,
    model: str | None = MODEL_OPT,
    rows: int | None = ROWS_OPT,
    cols: int | None = COLS_OPT,
    organize: OrganizeMethod | None = ORGANIZE_OPT,
    fmt: str | None = FORMAT_OPT,
    online: bool = typer.Option(True, "--online/--no-online", help="also run and show the online detectors"),
    log_every: int = typer.Option(1, "--log-every", min=1, help="log clouds and images on every n-th frame"),
    serve_web: bool = typer.Option(
        False, "--serve-web", help="serve the web viewer instead of spawning the desktop viewer (no display needed)"
    ),
    rrd: Path | None = typer.Option(None, "--rrd", help="write the recording here instead of spawning the viewer"),
    serve_seconds: float | None = SERVE_SECONDS_OPT,
    web_port: int | None = WEB_PORT_OPT,
    grpc_port: int | None = GRPC_PORT_OPT,
    bind: str = BIND_OPT,
) -> None:
    """Spawn the Rerun desktop viewer and watch PRC, the detectors and raw vs PRC-filtered odometry live
    (``--serve-web``: in a browser; ``--rrd FILE``: into a file to open later)."""
    from prc_slam.config import Config
    from prc_slam.jobs.common import Viewer
    from prc_slam.jobs.odometry import Interrupted, interrupted_line, run_odometry
    from prc_slam.jobs.progress import progress
    from prc_slam.prc.config import PRCConfig

    check_outputs(rrd=(rrd, "file"))
    spawn = not serve_web and rrd is None
    viewer = Viewer(
        rrd, None, serve_web, log_every, spawn=spawn, serve_seconds=serve_seconds, web_port=web_port,
        grpc_port=grpc_port, bind=bind, spawn_name="view",
    )  # fmt: skip
    cfg = Config(prc=PRCConfig.preset("multibeam"))
    try:
        with progress() as reporter:
            run, _ = run_odometry(
                input, cfg, ["raw", "prc"], fmt=fmt, max_frames=max_frames, online=online, viewer=viewer,
                reporter=reporter, **input_options(topic, meta, model, rows, cols, organize=organize),
            )  # fmt: skip
    except Interrupted as stop:
        raise fail(interrupted_line(stop, lambda part: []), 130) from None
    wrote(run.written)
