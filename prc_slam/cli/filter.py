"""``prc-slam filter``: the filtered stream out, for any SLAM system."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from prc_slam.cli.common import Mode, Preset, check_outputs, console, finish, handles_errors, in_progress, run_config
from prc_slam.cli.options import Json, MaxFrames, PrcPreset, ReaderOptions, grouped


@handles_errors
@grouped
def filter_stream(
    input: Path = typer.Argument(..., help="any supported input (bag, MCAP, Ouster pcap, PCD folder, KITTI, ...)"),
    out: Path = typer.Option(..., "--out", help="output: .mcap / .bag file, rosbag2 folder, PCD or KITTI folder"),
    keep_labels: str | None = typer.Option(
        None, "--keep-labels", help="comma-separated classes to keep (names or codes) instead of the filter policy"
    ),
    out_format: Literal["mcap", "ros2", "ros1", "pcd", "kitti"] | None = typer.Option(
        None, "--out-format", help="default: from --out, else the input's"
    ),
    label_type: Literal["uint8", "uint16"] = typer.Option(
        "uint8", "--label-type", help="type of the added label field"
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing output"),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban or forest"),
    preset: PrcPreset = Preset.multibeam,
    config: Path | None = typer.Option(None, help="YAML config (prc and filter sections)"),
    reader: ReaderOptions = ReaderOptions(),
    max_frames: MaxFrames = None,
    json_path: Json = None,
) -> None:
    """Every sweep after PRC and the filter policy (noise dropped, ground thinned), written in the
    input's kind where possible, with the same topic, frame id and stamps and a ``label`` field, so
    that KISS-ICP, FAST-LIO or LIO-SAM can replay it."""
    from prc_slam.jobs.filter import filter_job

    check_outputs(out=(out, "any"), json_path=(json_path, "file"))
    cfg = run_config(preset, config, mode)
    keep = None if keep_labels is None else [v.strip() for v in keep_labels.split(",") if v.strip()]
    if keep_labels is not None and not keep:
        raise ValueError("--keep-labels: give at least one class")
    metrics = in_progress(
        filter_job, input, cfg, out, fmt=reader.fmt, max_frames=max_frames, keep_labels=keep,
        out_format=out_format, label_dtype=label_type,
        overwrite=overwrite, **reader.open_options(),
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
    finish([out], json_path, metrics, cfg)
