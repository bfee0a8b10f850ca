"""``prc-slam classify`` and ``prc-slam detect``."""

from __future__ import annotations

from pathlib import Path

import typer

from prc_slam.cli.common import (
    BIND_OPT,
    COLS_OPT,
    CONNECT_OPT,
    EVERY_OPT,
    FORMAT_OPT,
    JSON_OPT,
    MAX_FRAMES_OPT,
    META_OPT,
    MODEL_OPT,
    ORGANIZE_OPT,
    ROWS_OPT,
    RRD_OPT,
    SERVE_OPT,
    TOPIC_OPT,
    ClassifyPreset,
    Mode,
    OrganizeMethod,
    Preset,
    check_outputs,
    class_table,
    console,
    handles_errors,
    input_options,
    prc_config,
    print_table,
    wrote,
)


def register(app: typer.Typer) -> None:
    app.command()(classify)
    app.command()(detect)


@handles_errors
def classify(
    input: Path = typer.Argument(..., help="any supported input (KITTI, Ouster pcap/npz, bag, MCAP, PCD folder, ...)"),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban or forest (Sec. II-F)"),
    preset: ClassifyPreset = typer.Option(
        ClassifyPreset.auto,
        help="paper parameters, our multi-beam setting, or auto: multibeam for spinning multi-beam sensors, else paper",
    ),
    adaptive: bool | None = typer.Option(None, "--adaptive/--fixed", help="scale xi_s, xi_p with slot spacing"),
    config: Path | None = typer.Option(None, help="YAML config (overrides mode/preset)"),
    topic: str | None = TOPIC_OPT,
    meta: Path | None = META_OPT,
    model: str | None = MODEL_OPT,
    rows: int | None = ROWS_OPT,
    cols: int | None = COLS_OPT,
    organize: OrganizeMethod | None = ORGANIZE_OPT,
    fmt: str | None = FORMAT_OPT,
    destaggered: bool = typer.Option(
        True,
        "--destaggered/--staggered",
        help="Ouster: rows shifted by pixel_shift_by_row (columns are azimuths), or in measurement order",
    ),
    max_frames: int | None = MAX_FRAMES_OPT,
    labels_out: Path | None = typer.Option(None, help="write NNNNNN.label per frame here"),
    las: Path | None = typer.Option(None, help="write the classified points as LAS 1.4 (.laz: compressed)"),
    json_path: Path | None = JSON_OPT,
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    bind: str = BIND_OPT,
    log_every: int = EVERY_OPT,
) -> None:
    """Classify every frame with PRC; score against ground truth when the input has it."""
    from prc_slam.config import Config
    from prc_slam.jobs.classify import Outputs, classify_job
    from prc_slam.jobs.common import Viewer, write_json
    from prc_slam.jobs.progress import progress
    from prc_slam.prc.config import PRCConfig

    check_outputs(labels_out=(labels_out, "dir"), las=(las, "file"), json_path=(json_path, "file"), rrd=(rrd, "file"))
    if preset is ClassifyPreset.auto and config is None:
        cfg = None  # decided on the first frame
    else:  # (a config file decides the preset)
        named = Preset.paper if preset is ClassifyPreset.auto else Preset(preset.value)
        cfg = prc_config(mode, named, adaptive, config)
    opts = input_options(topic, meta, model, rows, cols, destaggered, organize)
    viewer = Viewer(rrd, connect, serve_web, log_every, bind=bind)
    with progress() as reporter:
        metrics, written = classify_job(
            input, cfg, mode=mode.value, adaptive=adaptive, fmt=fmt, max_frames=max_frames,
            outputs=Outputs(labels_out, las), viewer=viewer, reporter=reporter, **opts,
        )  # fmt: skip
    summary(metrics, f"PRC on {input}")
    if json_path is not None:
        written += write_json(json_path, metrics, Config(prc=PRCConfig.model_validate(metrics["config"])))
    wrote(written)


def summary(metrics: dict, title: str) -> None:
    """The console summary of a ``classify`` run."""
    pps = metrics.get("points_per_s")
    console.print(
        f"{metrics['frames']} frames, {metrics['points']} points, PRC {metrics['seconds']:.3f} s"
        + (f" ({pps / 1e6:.1f} M points/s)" if pps else ""),
        highlight=False,
    )
    skipped = metrics.get("skipped_frames", 0) + metrics.get("skipped_points", 0) + metrics.get("empty_frames", 0)
    if skipped:
        console.print(
            f"skipped: {metrics['skipped_frames']} frames, {metrics['skipped_points']} points without a return "
            f"(NaN/inf, at the origin or beyond 100 km: label 0); {metrics['empty_frames']} empty frames",
            highlight=False,
        )
    if metrics.get("classes"):
        shares = ", ".join(f"{name} {c['share']:.1%}" for name, c in metrics["classes"].items())
        console.print(f"classes (share of the returns): {shares}", highlight=False)
    if "per_class" in metrics:
        print_table(class_table(metrics, title))
        console.print(
            f"reference ground/building/vegetation/trunk/vehicle/pole points labelled noise: "
            f"{metrics['noise_in_solid_classes']:.3%}",
            highlight=False,
        )


@handles_errors
def detect(
    input: Path = typer.Argument(..., help="any supported input (KITTI, Ouster pcap/npz, bag, MCAP, PCD folder, ...)"),
    topic: str | None = TOPIC_OPT,
    meta: Path | None = META_OPT,
    model: str | None = MODEL_OPT,
    rows: int | None = ROWS_OPT,
    cols: int | None = COLS_OPT,
    organize: OrganizeMethod | None = ORGANIZE_OPT,
    fmt: str | None = FORMAT_OPT,
    max_frames: int | None = MAX_FRAMES_OPT,
    labels_out: Path | None = typer.Option(None, help="write NNNNNN.label per frame here"),
    las: Path | None = typer.Option(None, help="write the labelled points as LAS 1.4 (.laz: compressed)"),
    json_path: Path | None = JSON_OPT,
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    bind: str = BIND_OPT,
    log_every: int = EVERY_OPT,
    paper: bool = typer.Option(
        False, "--paper", help="the paper's readings (our deviations off, except where profiler lines start)"
    ),
) -> None:
    """Online per-scan-line detectors (paper 001): horizontal / vertical / vegetation, ground,
    curbs with polylines and cars with boxes; scored against ground truth when the input has it."""
    from prc_slam.jobs.classify import Outputs, detect_job
    from prc_slam.jobs.common import Viewer, write_json
    from prc_slam.jobs.progress import progress

    check_outputs(labels_out=(labels_out, "dir"), las=(las, "file"), json_path=(json_path, "file"), rrd=(rrd, "file"))
    viewer = Viewer(rrd, connect, serve_web, log_every, bind=bind)
    with progress() as reporter:
        metrics, written = detect_job(
            input, paper=paper, fmt=fmt, max_frames=max_frames, outputs=Outputs(labels_out, las), viewer=viewer,
            reporter=reporter, **input_options(topic, meta, model, rows, cols, organize=organize),
        )  # fmt: skip
    seconds, points = metrics["seconds"], metrics["points"]
    warm = metrics["points_per_s_after_first"]
    console.print(
        f"{metrics['frames']} frames, {points} points, detectors {seconds:.2f} s"
        + (f" ({points / seconds / 1e6:.2f} M points/s" if seconds > 0 else "")
        + (f"; {warm / 1e6:.2f} M after the first frame" if warm else "")
        + (")" if seconds > 0 else ""),
        highlight=False,
    )
    if "per_class" in metrics:
        print_table(class_table(metrics, f"online detectors on {input}"))
        for name, o in metrics.get("objects", {}).items():
            console.print(f"{name} objects found: {o['found']} of {o['present']}", highlight=False)
        if "vehicle_by_range" in metrics:
            from prc_slam.evaluation.scoring import range_table

            print_table(range_table(metrics["vehicle_by_range"], "vehicle instances and points by range"))
    if json_path is not None:
        written += write_json(json_path, metrics)
    wrote(written)
