"""``prc-slam mapclass``."""

from __future__ import annotations

import contextlib
import functools
import os
from pathlib import Path
from typing import Any, Literal

import typer

from prc_slam.cli.common import check_outputs, class_table, console, finish, handles_errors, print_table, say
from prc_slam.cli.options import Json, MaxFrames, ReaderOptions, ServedRerunOptions, grouped


def print_mapclass(metrics: dict[str, Any], title: str) -> None:
    console.print(
        f"{metrics['points']:,} points in {metrics['seconds']:.2f} s ({metrics['points_per_s'] / 1e6:.2f} M points/s)"
        + (f", {metrics['tile']:g} m tiles" if metrics["tile"] else ""),
        highlight=False,
    )
    console.print("stages (s): " + ", ".join(f"{k} {v:.2f}" for k, v in metrics["seconds_per_stage"].items()))
    console.print("points per class: " + ", ".join(f"{k} {v:,}" for k, v in metrics["counts"].items()))
    terrain = (metrics.get("density") or {}).get("terrain_ground_share")
    if terrain:
        where = "" if terrain == 1 else f" on {terrain:.0%} of the tiles, the paper's level-ground test on the others"
        console.print(
            f"ground: terrain-relative tests (slopes, terraces; config ground.terrain){where}", highlight=False
        )
    raised = (metrics.get("density") or {}).get("raised_ground_cells")
    if raised:
        console.print(
            f"ground: in {raised:,} cells the lowest points were alone at their height (returns under the surface?) "
            "and the cell's height was taken from the lowest point with company (config ground.min_support)",
            highlight=False,
        )
    wooded = (metrics.get("density") or {}).get("canopy_share")
    if wooded:
        where = "" if wooded == 1 else f" on {wooded:.0%} of the tiles"
        console.print(
            f"vegetation: the foliage alone{where} (wooded: foliage is half the points off the ground or more; "
            "config vegetation.canopy_share)",
            highlight=False,
        )
    if metrics.get("points_not_written"):
        console.print(
            f"{metrics['points_not_written']:,} points without finite coordinates (no_return) are not in the LAS "
            f"files, which hold the other {metrics['points'] - metrics['points_not_written']:,} in input order",
            highlight=False,
        )
    if "per_class" in metrics:
        print_table(class_table(metrics, title))
        if "scored_points" in metrics:  # a map of frames of which only some carry reference labels
            console.print(
                f"scored on the {metrics['scored_points']:,} of {metrics['points']:,} "
                + metrics.get("scored_on", "points from frames with reference labels"),
                highlight=False,
            )
    for name, o in metrics.get("objects", {}).items():
        console.print(f"{name} objects found: {o['found']} of {o['present']}", highlight=False)
    if "prc_vs_map" in metrics:
        print_table(class_table(metrics["prc_vs_map"], "PRC labels against the map classification"))


@handles_errors
@grouped
def mapclass(
    input: Path = typer.Argument(..., help="cloud file (LAS/LAZ, PLY, PCD, NPY) or a sequence to accumulate"),
    out: Path = typer.Option(Path("out/mapclass"), help="output directory: one LAS 1.4 per class + combined"),
    json_path: Json = None,
    config: Path | None = typer.Option(None, help="YAML config (its mapclass section)"),
    normals: Literal["voxels", "points"] | None = typer.Option(
        None, help="normals/segmentation per voxel or per point (k-NN)"
    ),
    paper: bool = typer.Option(False, "--paper", help="the paper's steps only (our additions off)"),
    mode: Literal["urban", "forest"] | None = typer.Option(
        None, help="forest: slim pillars are stems (trunk), foliage is vegetation"
    ),
    tile: float | None = typer.Option(
        None, min=0.0, help="tile side (m); 0: one piece; default: tiles above 12 M points"
    ),
    margin: float = typer.Option(6.0, min=0.0, help="context around each tile (m)"),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="run the tiles on the Dask scheduler at this address (tcp://HOST:8786)"
    ),
    workers: int | None = typer.Option(None, "--workers", min=1, help="run the tiles on a local Dask cluster"),
    laz: bool = typer.Option(False, "--laz", help="write the combined and per-class clouds as LAZ"),
    reference: bool | None = typer.Option(
        None,
        "--reference/--no-reference",
        help="score a LAS/LAZ file against its own classes (default: if it has them)",
    ),
    reader: ReaderOptions = ReaderOptions(),
    max_frames: MaxFrames = None,
    every: int = typer.Option(1, min=1, help="sequence: accumulate every n-th frame"),
    poses: Path | None = typer.Option(None, help="sequence: poses (KITTI or TUM file) instead of ground truth"),
    rerun: ServedRerunOptions = ServedRerunOptions(),
    map_voxel: float = typer.Option(0.2, "--map-voxel", min=0.0, help="thin the logged map to this voxel (m)"),
) -> None:
    """Classify a registered map after registration (paper 004) and segregate it into
    per-class LAS files; scored against reference labels when a sequence has them.

    The tiles run on a Dask cluster with --scheduler or --workers, and on the scheduler at
    $DASK_SCHEDULER_ADDRESS when that is set."""
    from data_tools.formats.clouds import is_cloud_file
    from prc_slam.config import Config
    from prc_slam.jobs.mapclass import mapclass_job, refuse_sequence_options
    from prc_slam.jobs.progress import progress
    from prc_slam.mapclass import paper_config

    check_outputs(out=(out, "dir"), json_path=(json_path, "file"), rrd=(rerun.rrd, "file"))
    options = reader.open_options()
    if is_cloud_file(input):
        refuse_sequence_options(input, poses, max_frames, every, **options)
    cfg = Config.from_yaml(config) if config is not None else Config()
    if paper:
        cfg.mapclass = paper_config().model_copy(update={"normals": cfg.mapclass.normals})
    if normals is not None:
        cfg.mapclass.normals = normals
    if mode is not None:
        cfg.mapclass.mode = mode
    viewer = rerun.viewer(1, map_voxel=map_voxel)
    with contextlib.ExitStack() as stack:
        tiler = None
        if scheduler is not None or workers is not None or os.environ.get("DASK_SCHEDULER_ADDRESS"):
            from prc_slam.jobs.distributed import classify_tiled_distributed, open_client

            client = stack.enter_context(open_client(scheduler, workers, note=say))
            tiler = functools.partial(classify_tiled_distributed, client=client)
        reporter = stack.enter_context(progress())
        metrics = mapclass_job(
            input, cfg, out, tile=tile, margin=margin, fmt=reader.fmt, max_frames=max_frames, every=every, poses=poses,
            viewer=viewer, reporter=reporter, note=say, laz=laz, reference=reference, tiler=tiler,
            **options,
        )  # fmt: skip
    print_mapclass(metrics, f"map classification of {input}")
    finish([out / ("map_classified.laz" if laz else "map_classified.las")], json_path, metrics, cfg)
    console.print(f"one {'LAZ' if laz else 'LAS'} file per class in {out}", highlight=False)
