"""``prc-slam classify`` and ``prc-slam detect``."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from prc_slam.cli.common import (
    Mode,
    Preset,
    check_outputs,
    class_table,
    console,
    finish,
    handles_errors,
    in_progress,
    prc_config,
    print_table,
    print_vehicle_ranges,
)
from prc_slam.cli.options import (
    AnyInput,
    Json,
    LabelOutputs,
    LogEvery,
    MaxFrames,
    ReaderOptions,
    ServedRerunOptions,
    grouped,
)


@handles_errors
@grouped
def classify(
    input: AnyInput,
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban or forest (Sec. II-F)"),
    preset: Literal["auto", "paper", "multibeam"] = typer.Option(
        "auto",
        help="paper parameters, our multi-beam setting, or auto: multibeam for spinning multi-beam sensors, else paper",
    ),
    adaptive: bool | None = typer.Option(None, "--adaptive/--fixed", help="scale xi_s, xi_p with slot spacing"),
    config: Path | None = typer.Option(None, help="YAML config (overrides mode/preset)"),
    reader: ReaderOptions = ReaderOptions(),
    destaggered: bool = typer.Option(
        True,
        "--destaggered/--staggered",
        help="Ouster: rows shifted by pixel_shift_by_row (columns are azimuths), or in measurement order",
    ),
    max_frames: MaxFrames = None,
    outputs: LabelOutputs = LabelOutputs(),
    json_path: Json = None,
    rerun: ServedRerunOptions = ServedRerunOptions(),
    log_every: LogEvery = 5,
) -> None:
    """Classify every frame with PRC; score against ground truth when the input has it."""
    from prc_slam.config import Config
    from prc_slam.jobs.classify import classify_job
    from prc_slam.prc.config import PRCConfig

    check_outputs(labels_out=(outputs.labels_out, "dir"), las=(outputs.las, "file"), json_path=(json_path, "file"))
    check_outputs(rrd=(rerun.rrd, "file"))
    if preset == "auto" and config is None:
        cfg = None  # decided on the first frame
    else:  # (a config file decides the preset)
        named = Preset.paper if preset == "auto" else Preset(preset)
        cfg = prc_config(mode, named, adaptive, config)
    opts = reader.open_options(destaggered)
    metrics, written = in_progress(
        classify_job, input, cfg, mode=mode.value, adaptive=adaptive, fmt=reader.fmt, max_frames=max_frames,
        outputs=outputs.job_outputs(), viewer=rerun.viewer(log_every), **opts,
    )  # fmt: skip
    summary(metrics, f"PRC on {input}")
    used = None if json_path is None else Config(prc=PRCConfig.model_validate(metrics["config"]))
    finish(written, json_path, metrics, used)


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
@grouped
def detect(
    input: AnyInput,
    reader: ReaderOptions = ReaderOptions(),
    max_frames: MaxFrames = None,
    outputs: LabelOutputs = LabelOutputs(),
    json_path: Json = None,
    rerun: ServedRerunOptions = ServedRerunOptions(),
    log_every: LogEvery = 5,
    paper: bool = typer.Option(
        False, "--paper", help="the paper's readings (our deviations off, except where profiler lines start)"
    ),
) -> None:
    """Online per-scan-line detectors (paper 001): horizontal / vertical / vegetation, ground,
    curbs with polylines and cars with boxes; scored against ground truth when the input has it."""
    from prc_slam.jobs.classify import detect_job

    check_outputs(labels_out=(outputs.labels_out, "dir"), las=(outputs.las, "file"), json_path=(json_path, "file"))
    check_outputs(rrd=(rerun.rrd, "file"))
    metrics, written = in_progress(
        detect_job, input, paper=paper, fmt=reader.fmt, max_frames=max_frames, outputs=outputs.job_outputs(),
        viewer=rerun.viewer(log_every), **reader.open_options(),
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
        print_vehicle_ranges(metrics)
    finish(written, json_path, metrics)
