"""``prc-slam filter``: the filtered stream out, for any SLAM system."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer

from prc_slam.cli.common import (
    COLS_OPT,
    FORMAT_OPT,
    JSON_OPT,
    MAX_FRAMES_OPT,
    META_OPT,
    MODEL_OPT,
    ORGANIZE_OPT,
    ROWS_OPT,
    Mode,
    OrganizeMethod,
    Preset,
    check_outputs,
    console,
    handles_errors,
    input_options,
    run_config,
    wrote,
)


def register(app: typer.Typer) -> None:
    app.command(name="filter")(filter_stream)


class OutFormat(str, Enum):
    mcap = "mcap"
    ros2 = "ros2"
    ros1 = "ros1"
    pcd = "pcd"
    kitti = "kitti"


class LabelType(str, Enum):
    uint8 = "uint8"
    uint16 = "uint16"


@handles_errors
def filter_stream(
    input: Path = typer.Argument(..., help="any supported input (bag, MCAP, Ouster pcap, PCD folder, KITTI, ...)"),
    out: Path = typer.Option(..., "--out", help="output: .mcap / .bag file, rosbag2 folder, PCD or KITTI folder"),
    keep_labels: str | None = typer.Option(
        None, "--keep-labels", help="comma-separated classes to keep (names or codes) instead of the filter policy"
    ),
    out_format: OutFormat | None = typer.Option(None, "--out-format", help="default: from --out, else the input's"),
    label_type: LabelType = typer.Option(LabelType.uint8, "--label-type", help="type of the added label field"),
    topic: str | None = typer.Option(None, "--topic", help="bags/MCAP: the PointCloud2 topic (when several)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing output"),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban or forest"),
    preset: Preset = typer.Option(Preset.multibeam, help="PRC parameters"),
    config: Path | None = typer.Option(None, help="YAML config (prc and filter sections)"),
    meta: Path | None = META_OPT,
    model: str | None = MODEL_OPT,
    rows: int | None = ROWS_OPT,
    cols: int | None = COLS_OPT,
    organize: OrganizeMethod | None = ORGANIZE_OPT,
    fmt: str | None = FORMAT_OPT,
    max_frames: int | None = MAX_FRAMES_OPT,
    json_path: Path | None = JSON_OPT,
) -> None:
    """Every sweep after PRC and the filter policy (noise dropped, ground thinned), written in the
    input's kind where possible, with the same topic, frame id and stamps and a ``label`` field, so
    that KISS-ICP, FAST-LIO or LIO-SAM can replay it."""
    from prc_slam.jobs.common import write_json
    from prc_slam.jobs.filter import filter_job
    from prc_slam.jobs.progress import progress

    check_outputs(out=(out, "any"), json_path=(json_path, "file"))
    cfg = run_config(preset, config, mode)
    keep = None if keep_labels is None else [v.strip() for v in keep_labels.split(",") if v.strip()]
    if keep_labels is not None and not keep:
        raise ValueError("--keep-labels: give at least one class")
    with progress() as reporter:
        metrics = filter_job(
            input, cfg, out, fmt=fmt, max_frames=max_frames, keep_labels=keep,
            out_format=None if out_format is None else out_format.value, label_dtype=label_type.value,
            overwrite=overwrite, reporter=reporter, **input_options(topic, meta, model, rows, cols, organize=organize),
        )  # fmt: skip
    kept = metrics.get("kept_fraction")
    console.print(
        f"{metrics['frames']} frames, {metrics['points_in']:,} points in, {metrics['points_kept']:,} kept"
        + (f" ({kept:.1%})" if kept is not None else "")
        + f" -> {metrics['out']} ({metrics.get('out_format')})",
        highlight=False,
    )
    for name, c in metrics.get("per_class", {}).items():
        console.print(f"  {name}: {c['in']:,} in, {c['kept']:,} kept", highlight=False)
    written = [out]
    if json_path is not None:
        written += write_json(json_path, metrics, cfg)
    wrote(written)
