"""``prc-slam``: the command-line interface (typer)."""

from __future__ import annotations

import json
from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from prc_slam.config import Config, PRCConfig

app = typer.Typer(no_args_is_help=True, add_completion=False, help="Preregistration classification for LiDAR odometry.")
console = Console(stderr=True, soft_wrap=True)
DEFAULT_KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti00"


class Mode(str, Enum):
    urban = "urban"
    forest = "forest"


class Preset(str, Enum):
    paper = "paper"
    multibeam = "multibeam"


def _progress() -> Progress:
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    )


def _fail(message: str) -> typer.Exit:
    console.print(f"[red]error:[/red] {message}")
    return typer.Exit(code=2)


def _write_json(path: Path, data: dict[str, Any], config: Config | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    if config is not None:
        config.to_yaml(path.with_name(path.stem + ".config.yaml"))
    console.print(f"wrote {path}")


def _json_default(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


class Viewer:
    """Options shared by long-running commands: where the Rerun recording goes."""

    def __init__(
        self,
        rrd: Path | None,
        connect: str | None,
        serve_web: bool,
        every: int,
        spawn: bool = False,
        serve_seconds: float | None = None,
        map_voxel: float = 0.5,
    ):
        self.sink = None
        self.serve_web, self.serve_seconds = serve_web, serve_seconds
        if rrd is None and connect is None and not serve_web and not spawn:
            return
        from prc_slam.viz.sink import RerunSink, VizConfig, open_recording

        if rrd is not None:
            rrd.parent.mkdir(parents=True, exist_ok=True)
        rec, address = open_recording(
            rrd=None if rrd is None else str(rrd), connect=connect, serve_web=serve_web, spawn=spawn
        )
        self.sink = RerunSink(rec, VizConfig(every=every, map_voxel=map_voxel))
        self.rrd = rrd
        if address:
            console.print(f"web viewer: {address}")

    def close(self) -> None:
        if self.sink is None:
            return
        self.sink.rec.flush()
        if self.rrd is not None:
            console.print(f"wrote {self.rrd} (open it with: .venv/bin/rerun {self.rrd})")
        if self.serve_web:
            import time

            limit = "" if self.serve_seconds is None else f" for {self.serve_seconds:g} s"
            console.print(f"run finished; still serving the web viewer{limit} (Ctrl-C to stop)")
            deadline = None if self.serve_seconds is None else time.monotonic() + self.serve_seconds
            try:
                while deadline is None or time.monotonic() < deadline:
                    time.sleep(0.2)
            except KeyboardInterrupt:
                pass


class LasCollector:
    """Labelled points of every frame (world frame when the frame has a pose), written as one
    LAS 1.4 file with the frame index in ``point_source_id``; a no-op without a path."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []

    def add(self, scan, codes: np.ndarray) -> None:
        if self.path is None:
            return
        xyz = scan.points()
        if scan.gt_pose is not None:
            xyz = xyz @ scan.gt_pose[:3, :3].T + scan.gt_pose[:3, 3]
        self.parts.append((xyz, codes))

    def write(self) -> None:
        if self.path is None or not self.parts:
            return
        from data_tools.writers import write_las

        write_las(
            self.path,
            np.concatenate([p[0] for p in self.parts]),
            np.concatenate([p[1] for p in self.parts]),
            point_source_id=np.concatenate([np.full(len(p[0]), i) for i, p in enumerate(self.parts)]),
        )
        console.print(f"wrote {self.path}")


RRD_OPT = typer.Option(None, "--rrd", help="write a Rerun recording (.rrd) here")
CONNECT_OPT = typer.Option(None, "--connect", help="stream to a running Rerun viewer (rerun+http://host:9876/proxy)")
SERVE_OPT = typer.Option(False, "--serve-web", help="serve the Rerun web viewer on localhost and print its address")
EVERY_OPT = typer.Option(5, "--log-every", min=1, help="log clouds and images on every n-th frame")
MAP_VOXEL_OPT = typer.Option(0.5, "--map-voxel", min=0.0, help="thin the logged local map to this voxel (m)")
SERVE_SECONDS_OPT = typer.Option(None, "--serve-seconds", help="with --serve-web: stop serving after this long")


def _prc_config(mode: Mode, preset: Preset, adaptive: bool | None, config_path: Path | None) -> PRCConfig:
    if config_path is not None:
        cfg = Config.from_yaml(config_path).prc
    elif preset is Preset.multibeam:
        cfg = PRCConfig.preset("multibeam")
    else:
        cfg = PRCConfig.preset(mode.value)
    updates: dict[str, Any] = {}
    if config_path is None and preset is Preset.multibeam and mode is Mode.forest:
        updates["mode"] = "forest"
    if adaptive is not None:
        updates["adaptive"] = adaptive
    return cfg.model_copy(update=updates) if updates else cfg


def print_class_table(metrics: dict[str, Any], title: str) -> None:
    """Per-class precision / recall / F1 as a table on the console."""
    table = Table(title=title)
    for col in ("class", "support", "precision", "recall", "f1"):
        table.add_column(col, justify="right" if col != "class" else "left")

    def fmt(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    for name, s in metrics.get("per_class", {}).items():
        table.add_row(name, str(s["support"]), fmt(s["precision"]), fmt(s["recall"]), fmt(s["f1"]))
    Console().print(table)


@app.command()
def classify(
    input: Path = typer.Argument(..., help="KITTI sequence directory, Ouster .npz file or directory"),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban or forest (Sec. II-F)"),
    preset: Preset = typer.Option(Preset.paper, help="paper parameters, or our multi-beam setting"),
    adaptive: bool | None = typer.Option(None, "--adaptive/--fixed", help="scale xi_s, xi_p with slot spacing"),
    config: Path | None = typer.Option(None, help="YAML config (overrides mode/preset)"),
    fmt: str | None = typer.Option(None, "--format", help="input format (default: detected)"),
    destaggered: bool = typer.Option(False, help="Ouster: destagger rows by pixel_shift_by_row"),
    max_frames: int | None = typer.Option(None, help="classify only the first N frames"),
    labels_out: Path | None = typer.Option(None, help="write NNNNNN.label per frame here"),
    las: Path | None = typer.Option(None, help="write the classified points as LAS 1.4"),
    json_path: Path | None = typer.Option(None, "--json", help="write the metrics JSON here"),
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    log_every: int = EVERY_OPT,
) -> None:
    """Classify every frame with PRC; score against ground truth when the input has it."""
    from data_tools import DataError, open_dataset
    from data_tools.writers import write_label_file
    from prc_slam.classify_run import run_classification

    try:
        dataset = open_dataset(input, fmt, destaggered=destaggered)
        cfg = _prc_config(mode, preset, adaptive, config)
    except (DataError, ValueError) as exc:
        raise _fail(str(exc)) from exc
    n = len(dataset) if max_frames is None else min(max_frames, len(dataset))
    collector = LasCollector(las)
    viewer = Viewer(rrd, connect, serve_web, log_every)

    done = [0]

    with _progress() as progress:
        task = progress.add_task("PRC", total=n)

        def on_frame(frame) -> None:
            progress.advance(task)
            if viewer.sink is not None:
                viewer.sink.log_classified(done[0], frame.scan, frame.labels)
            done[0] += 1
            collector.add(frame.scan, frame.point_labels())

        try:
            metrics = run_classification(
                (dataset[i] for i in range(n)),
                cfg,
                labels_out=labels_out,
                label_writer=write_label_file,
                on_frame=on_frame,
            )
        except (DataError, ValueError) as exc:
            raise _fail(str(exc)) from exc
    viewer.close()
    metrics["input"] = str(input)
    metrics["config"] = cfg.model_dump(mode="json")
    collector.write()
    _report(metrics, f"PRC on {input}")
    if json_path is not None:
        _write_json(json_path, metrics, Config(prc=cfg))


def _report(metrics: dict[str, Any], title: str) -> None:
    pps = metrics.get("points_per_s")
    console.print(
        f"{metrics['frames']} frames, {metrics['points']} points, PRC {metrics['seconds']:.3f} s"
        + (f" ({pps / 1e6:.1f} M points/s)" if pps else "")
    )
    if "per_class" in metrics:
        print_class_table(metrics, title)
        console.print(
            f"reference ground/building/vegetation/trunk/vehicle/pole points labelled noise: "
            f"{metrics['noise_in_solid_classes']:.3%}"
        )


class FilterMode(str, Enum):
    none = "none"
    prc = "prc"


class Matching(str, Enum):
    plain = "plain"
    class_aware = "class-aware"


class PoseFormat(str, Enum):
    kitti = "kitti"
    tum = "tum"


def _run_config(preset: Preset, config_path: Path | None, mode: Mode = Mode.urban) -> Config:
    from prc_slam.odometry.classaware import ClassAwareConfig

    if config_path is not None:
        return Config.from_yaml(config_path)
    return Config(prc=_prc_config(mode, preset, None, None), classaware=ClassAwareConfig.for_mode(mode.value))


def _compare(
    input: Path,
    variants: list[str],
    cfg: Config,
    fmt: str | None,
    max_frames: int | None,
    viewer: Viewer | None = None,
    also: Callable[[Any], None] | None = None,
):
    from data_tools import open_dataset
    from prc_slam.odometry.compare import run_compare

    dataset = open_dataset(input, fmt)
    n = len(dataset) if max_frames is None else min(max_frames, len(dataset))
    sink = viewer.sink if viewer is not None else None
    with _progress() as progress:
        task = progress.add_task("odometry " + " | ".join(variants), total=n)

        def on_frame(record) -> None:
            progress.advance(task)
            if sink is not None:
                sink.log_record(record, gt_pose=record.frame.scan.gt_pose)
            if also is not None:
                also(record)

        result = run_compare((dataset[i] for i in range(n)), cfg, variants, on_frame=on_frame)
    if viewer is not None:
        viewer.close()
    return result


def print_variant_table(metrics: dict[str, Any], title: str) -> None:
    from prc_slam.report import FIELDS, _fmt

    variants = metrics["variants"]
    fields = [f for f in FIELDS if any(f in m for m in variants.values())]
    table = Table(title=title)
    table.add_column("variant")
    for f in fields:
        table.add_column(f, justify="right")
    for name, m in variants.items():
        table.add_row(name, *(_fmt(m.get(f)) for f in fields))
    Console().print(table)


@app.command()
def compare(
    input: Path = typer.Argument(..., help="KITTI directory, simulated sequence, or Ouster .npz files"),
    variants: str = typer.Option("raw,prc", help="comma-separated variants: raw, prc, prc+classaware"),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban, or forest (trunks for class-aware matching)"),
    deskew: bool = typer.Option(True, "--deskew/--no-deskew", help="KISS-ICP's constant-velocity deskewing"),
    out: Path = typer.Option(Path("out/compare"), help="output directory"),
    preset: Preset = typer.Option(Preset.multibeam, help="PRC parameters for the prc variant"),
    config: Path | None = typer.Option(None, help="YAML config (prc, filter, odometry sections)"),
    fmt: str | None = typer.Option(None, "--format", help="input format (default: detected)"),
    max_frames: int | None = typer.Option(None, help="use only the first N frames"),
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    log_every: int = EVERY_OPT,
    serve_seconds: float | None = SERVE_SECONDS_OPT,
    mapclass: bool = typer.Option(False, "--mapclass", help="also classify the run's map (paper 004) vs PRC"),
    mapclass_every: int = typer.Option(5, min=1, help="with --mapclass: accumulate every n-th frame"),
) -> None:
    """Run odometry variants side by side in one process (same KISS-ICP settings) and write
    report.md, metrics.json, trajectories (KITTI and TUM), the config used and plots. With
    ``--mapclass``: accumulate the map at the PRC variant's poses, classify it after
    registration and report the agreement of PRC labels with it (mapclass.json, report.md)."""
    from data_tools import DataError, open_dataset
    from data_tools.trajectory_io import write_kitti_poses, write_tum_poses
    from prc_slam.report import write_compare_outputs

    names = [v.strip() for v in variants.split(",") if v.strip()]
    prc_labels: dict[int, np.ndarray] = {}

    def keep_labels(record) -> None:
        if mapclass and record.index % mapclass_every == 0 and record.frame.labels is not None:
            prc_labels[record.index] = record.frame.point_labels()

    try:
        cfg = _run_config(preset, config, mode)
        cfg.odometry.deskew = cfg.odometry.deskew and deskew
        viewer = Viewer(rrd, connect, serve_web, log_every, serve_seconds=serve_seconds)
        result = _compare(input, names, cfg, fmt, max_frames, viewer, also=keep_labels)
    except (DataError, ValueError) as exc:
        raise _fail(str(exc)) from exc
    metrics = write_compare_outputs(
        result, cfg, out, f"Odometry comparison on {input}", write_kitti_poses, write_tum_poses
    )
    print_variant_table(metrics, f"odometry on {input}")
    console.print(f"wrote {out}/report.md, metrics.json, trajectories and trajectories.png")
    if mapclass:
        from prc_slam.mapclass.tiles import array_chunks
        from prc_slam.report import mapclass_section

        variant = next((v for v in names if v != "raw"), names[0])
        dataset = open_dataset(input, fmt)
        n = len(result.times)
        cloud = _map_from_dataset(dataset, n, mapclass_every, result.estimate_in_world(variant), prc_labels or None)
        console.print(f"map: {len(cloud):,} points from every {mapclass_every}th frame at the {variant} poses")
        mc = _mapclass_outputs(
            lambda: array_chunks(cloud.points), len(cloud), cfg, out / "mapclass", None, 6.0,
            cloud.attributes.get("reference"), cloud.attributes.get("instance"), cloud.attributes.get("prc"),
        )  # fmt: skip
        mc["poses"] = variant
        _write_json(out / "mapclass.json", mc)
        with (out / "report.md").open("a") as f:
            f.write(mapclass_section(mc))
        _print_mapclass(mc, "map classification")


@app.command()
def odometry(
    input: Path = typer.Argument(..., help="KITTI directory, simulated sequence, or Ouster .npz files"),
    filter: FilterMode = typer.Option(FilterMode.prc, "--filter", help="none: every point; prc: PRC filter"),
    matching: Matching = typer.Option(Matching.plain, help="plain KISS-ICP, or class-aware (needs --filter prc)"),
    mode: Mode = typer.Option(Mode.urban, help="PRC classes: urban, or forest"),
    deskew: bool = typer.Option(True, "--deskew/--no-deskew", help="KISS-ICP's constant-velocity deskewing"),
    preset: Preset = typer.Option(Preset.multibeam, help="PRC parameters"),
    config: Path | None = typer.Option(None, help="YAML config (prc, filter, odometry sections)"),
    poses_out: Path | None = typer.Option(None, help="write the trajectory here"),
    pose_format: PoseFormat = typer.Option(PoseFormat.kitti, help="trajectory file format"),
    json_path: Path | None = typer.Option(None, "--json", help="write the metrics JSON here"),
    fmt: str | None = typer.Option(None, "--format", help="input format (default: detected)"),
    max_frames: int | None = typer.Option(None, help="use only the first N frames"),
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    log_every: int = EVERY_OPT,
) -> None:
    """KISS-ICP odometry on every frame, on all points or on the PRC-filtered ones."""
    from data_tools import DataError
    from data_tools.trajectory_io import write_kitti_poses, write_tum_poses

    if matching is Matching.class_aware and filter is FilterMode.none:
        raise _fail("--matching class-aware needs PRC labels: use it with --filter prc")
    name = "raw" if filter is FilterMode.none else "prc+classaware" if matching is Matching.class_aware else "prc"
    try:
        cfg = _run_config(preset, config, mode)
        cfg.odometry.deskew = cfg.odometry.deskew and deskew
        result = _compare(input, [name], cfg, fmt, max_frames, Viewer(rrd, connect, serve_web, log_every))
    except (DataError, ValueError) as exc:
        raise _fail(str(exc)) from exc
    metrics = result.metrics()
    if poses_out is not None:
        poses = result.estimate_in_world(name)
        if pose_format is PoseFormat.kitti:
            write_kitti_poses(poses_out, poses)
        else:
            write_tum_poses(poses_out, result.times, poses)
        console.print(f"wrote {poses_out}")
    print_variant_table(metrics, f"odometry on {input}")
    if json_path is not None:
        _write_json(json_path, metrics, cfg)


@app.command()
def view(
    input: Path = typer.Argument(..., help="KITTI directory, simulated sequence, or Ouster .npz files"),
    max_frames: int | None = typer.Option(None, help="use only the first N frames"),
    log_every: int = typer.Option(1, "--log-every", min=1, help="log clouds and images on every n-th frame"),
) -> None:
    """Spawn the Rerun desktop viewer and watch PRC and raw vs PRC-filtered odometry live."""
    cfg = Config(prc=PRCConfig.preset("multibeam"))
    _compare(input, ["raw", "prc"], cfg, None, max_frames, Viewer(None, None, False, log_every, spawn=True))


@app.command()
def detect(
    input: Path = typer.Argument(..., help="KITTI directory, simulated sequence, or Ouster .npz files"),
    fmt: str | None = typer.Option(None, "--format", help="input format (default: detected)"),
    max_frames: int | None = typer.Option(None, help="use only the first N frames"),
    labels_out: Path | None = typer.Option(None, help="write NNNNNN.label per frame here"),
    las: Path | None = typer.Option(None, help="write the labelled points as LAS 1.4"),
    json_path: Path | None = typer.Option(None, "--json", help="write the metrics JSON here"),
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    log_every: int = EVERY_OPT,
    paper: bool = typer.Option(
        False, "--paper", help="the paper's readings (our deviations off, except where profiler lines start)"
    ),
) -> None:
    """Online per-scan-line detectors (paper 001): horizontal / vertical / vegetation, ground,
    curbs with polylines and cars with boxes; scored against ground truth when the input has it."""
    from data_tools import DataError, open_dataset
    from data_tools.writers import write_label_file
    from prc_slam import labels as L
    from prc_slam.evaluation import ConfusionAccumulator, objects_found
    from prc_slam.online import OnlineDetector

    try:
        dataset = open_dataset(input, fmt)
    except (DataError, ValueError) as exc:
        raise _fail(str(exc)) from exc
    n = len(dataset) if max_frames is None else min(max_frames, len(dataset))
    viewer = Viewer(rrd, connect, serve_web, log_every)
    detector = OnlineDetector.paper() if paper else OnlineDetector()
    confusion = ConfusionAccumulator()
    have_gt, points, seconds, curbs = False, 0, 0.0, 0
    first_points, first_seconds = 0, 0.0
    objects = {L.VEHICLE: np.zeros(2, int), L.CURB: np.zeros(2, int)}  # found, present, summed over frames
    collector = LasCollector(las)
    with _progress() as progress:
        task = progress.add_task("online detectors", total=n)
        for i in range(n):
            try:
                scan = dataset[i]
            except DataError as exc:
                raise _fail(str(exc)) from exc
            result = detector.process(scan)
            seconds += result.seconds
            points += scan.n_points
            if i == 0:  # the first frame also loads the compiled kernels
                first_points, first_seconds = scan.n_points, result.seconds
            curbs += len(result.curb_polylines)
            codes = scan.per_point(result.labels)
            if labels_out is not None:
                write_label_file(labels_out / f"{scan.name}.label", codes)
            ref = scan.reference_labels()
            if ref is not None:
                have_gt = True
                confusion.add(ref, codes)
            if scan.gt_labels is not None and scan.gt_instance is not None:
                for code in (L.VEHICLE, L.CURB):
                    found, present = objects_found(scan.gt_labels, scan.gt_instance, result.labels, code)
                    objects[code] += np.array([found, present])
            collector.add(scan, codes)
            if viewer.sink is not None:
                viewer.sink.log_classified(i, scan, result.labels)
                viewer.sink.log_online(i, scan, result, scan.gt_pose)
            progress.advance(task)
    viewer.close()
    metrics: dict[str, Any] = {
        "frames": n,
        "points": points,
        "seconds": seconds,
        "seconds_first": first_seconds,
        "points_per_s": points / seconds if seconds > 0 else None,
        "points_per_s_after_first": (
            (points - first_points) / (seconds - first_seconds) if seconds > first_seconds else None
        ),
        "curb_polylines_per_frame": curbs / max(n, 1),
        "input": str(input),
    }
    if have_gt:
        metrics["per_class"] = confusion.per_class()
        metrics["confusion"] = confusion.to_json()
        # per frame: vehicles, and curb sections (simulated scenes; SemanticKITTI has no curbs)
        metrics["objects"] = {
            L.CODE_TO_NAME[code]: {"found": int(fp[0]), "present": int(fp[1])} for code, fp in objects.items()
        }
    collector.write()
    console.print(
        f"{n} frames, {points} points, detectors {seconds:.2f} s"
        + (f" ({points / seconds / 1e6:.2f} M points/s" if seconds > 0 else "")
        + (f"; {warm / 1e6:.2f} M after the first frame" if (warm := metrics["points_per_s_after_first"]) else "")
        + (")" if seconds > 0 else "")
    )
    if have_gt:
        print_class_table(metrics, f"online detectors on {input}")
    if json_path is not None:
        _write_json(json_path, metrics)


class Normals(str, Enum):
    voxels = "voxels"
    points = "points"


def _map_from_dataset(
    dataset, n: int, every: int, poses: Path | np.ndarray | None, prc: dict[int, np.ndarray] | None = None
):
    """Accumulate every ``every``-th of the first ``n`` frames at the given poses (an array, a
    KITTI pose file, or None for the sequence's ground truth), carrying reference labels and
    instances when present and PRC labels for the frames in ``prc``."""
    from data_tools.kitti import read_kitti_poses
    from prc_slam.mapclass import accumulate

    source = "ground truth" if poses is None else str(poses) if isinstance(poses, Path) else "the estimate"
    if isinstance(poses, Path):
        poses = read_kitti_poses(poses)
    elif poses is None:
        poses = getattr(dataset, "poses", None)
    if poses is None:
        raise ValueError("the input has no ground-truth poses; give --poses (KITTI format)")
    if len(poses) < n:
        raise ValueError(f"{source}: {len(poses)} poses for {n} frames")
    times = getattr(dataset, "times", None)
    times = np.arange(n) * 0.1 if times is None else np.asarray(times, dtype=float)

    def frames():
        for i in range(0, n, every):
            scan = dataset[i]
            extra = {}
            ref = scan.reference_labels()
            if ref is not None:
                extra["reference"] = ref
                if scan.gt_instance is not None:
                    extra["instance"] = scan.per_point(scan.gt_instance)
            if prc is not None and i in prc:
                extra["prc"] = prc[i]
            yield i, scan, extra

    return accumulate(frames(), np.asarray(poses)[:n], times[:n])


def _mapclass_outputs(
    points_source,
    n_points: int,
    cfg: Config,
    out: Path,
    tile: float | None,
    margin: float,
    reference=None,
    instance=None,
    prc=None,
    viewer: Viewer | None = None,
) -> dict[str, Any]:
    """Classify, write the per-class LAS files, score; returns the metrics. Tiled runs keep the
    labels in a memory-mapped scratch file (one byte per point), so the map never has to fit."""
    import tempfile

    from data_tools.writers import ClassSplitWriter
    from prc_slam.mapclass_run import UNTILED_MAX_POINTS, prc_agreement, run_mapclass, score_map

    out.mkdir(parents=True, exist_ok=True)
    tiled = tile > 0 if tile is not None else n_points > UNTILED_MAX_POINTS
    with tempfile.TemporaryDirectory(dir=out) as scratch, _progress() as progress:
        store = np.memmap(Path(scratch) / "labels.u8", np.uint8, "w+", shape=(max(n_points, 1),)) if tiled else None
        task = progress.add_task("map classification (tiles)", total=None)
        labels, metrics = run_mapclass(
            points_source, n_points, cfg.mapclass, tile, margin, labels_out=None if store is None else store[:n_points],
            progress=lambda done, total: progress.update(task, completed=done, total=total),
        )  # fmt: skip
        with ClassSplitWriter(out) as writer:
            start = 0
            for part, chunk in enumerate(points_source()):
                writer.write(chunk, labels[start : start + len(chunk)])
                if viewer is not None and viewer.sink is not None:
                    viewer.sink.log_map(chunk, labels[start : start + len(chunk)], part)
                start += len(chunk)
        labels = np.array(labels) if reference is not None or prc is not None else None
        del store
    metrics["files"] = {k: str(v) for k, v in writer.paths.items()}
    if reference is not None:
        metrics.update(score_map(labels, reference, instance))
    if prc is not None:
        metrics["prc_vs_map"] = prc_agreement(prc, labels)
    return metrics


def _print_mapclass(metrics: dict[str, Any], title: str) -> None:
    console.print(
        f"{metrics['points']:,} points in {metrics['seconds']:.2f} s ({metrics['points_per_s'] / 1e6:.2f} M points/s)"
        + (f", {metrics['tile']:g} m tiles" if metrics["tile"] else "")
    )
    console.print("stages (s): " + ", ".join(f"{k} {v:.2f}" for k, v in metrics["seconds_per_stage"].items()))
    console.print("points per class: " + ", ".join(f"{k} {v:,}" for k, v in metrics["counts"].items()))
    if "per_class" in metrics:
        print_class_table(metrics, title)
    for name, o in metrics.get("objects", {}).items():
        console.print(f"{name} objects found: {o['found']} of {o['present']}")
    if "prc_vs_map" in metrics:
        print_class_table(metrics["prc_vs_map"], "PRC labels against the map classification")


@app.command()
def mapclass(
    input: Path = typer.Argument(..., help="cloud file (LAS/LAZ, PLY, PCD, NPY) or a sequence to accumulate"),
    out: Path = typer.Option(Path("out/mapclass"), help="output directory: one LAS 1.4 per class + combined"),
    json_path: Path | None = typer.Option(None, "--json", help="write the metrics JSON here"),
    config: Path | None = typer.Option(None, help="YAML config (its mapclass section)"),
    normals: Normals | None = typer.Option(None, help="normals/segmentation per voxel or per point (k-NN)"),
    paper: bool = typer.Option(False, "--paper", help="the paper's steps only (our additions off)"),
    tile: float | None = typer.Option(
        None, min=0.0, help="tile side (m); 0: one piece; default: tiles above 12 M points"
    ),
    margin: float = typer.Option(6.0, min=0.0, help="context around each tile (m)"),
    fmt: str | None = typer.Option(None, "--format", help="sequence format (default: detected)"),
    max_frames: int | None = typer.Option(None, help="sequence: accumulate only the first N frames"),
    every: int = typer.Option(1, min=1, help="sequence: accumulate every n-th frame"),
    poses: Path | None = typer.Option(None, help="sequence: poses (KITTI format) instead of ground truth"),
    rrd: Path | None = RRD_OPT,
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    map_voxel: float = typer.Option(0.2, "--map-voxel", min=0.0, help="thin the logged map to this voxel (m)"),
) -> None:
    """Classify a registered map after registration (paper 004) and segregate it into
    per-class LAS files; scored against reference labels when a sequence has them."""
    from data_tools import DataError, open_dataset
    from data_tools.clouds import cloud_chunks, cloud_size, is_cloud_file
    from prc_slam.mapclass import paper_config
    from prc_slam.mapclass.tiles import array_chunks

    cfg = Config.from_yaml(config) if config is not None else Config()
    if paper:
        cfg.mapclass = paper_config().model_copy(update={"normals": cfg.mapclass.normals})
    if normals is not None:
        cfg.mapclass.normals = normals.value
    viewer = Viewer(rrd, connect, serve_web, 1, map_voxel=map_voxel)
    try:
        if is_cloud_file(input):
            metrics = _mapclass_outputs(
                lambda: cloud_chunks(input), cloud_size(input), cfg, out, tile, margin, viewer=viewer
            )
        else:
            dataset = open_dataset(input, fmt)
            n = len(dataset) if max_frames is None else min(max_frames, len(dataset))
            cloud = _map_from_dataset(dataset, n, every, poses)
            console.print(f"accumulated {len(cloud):,} points from {len(range(0, n, every))} frames")
            metrics = _mapclass_outputs(
                lambda: array_chunks(cloud.points), len(cloud), cfg, out, tile, margin,
                cloud.attributes.get("reference"), cloud.attributes.get("instance"), viewer=viewer,
            )  # fmt: skip
    except (DataError, ValueError) as exc:
        raise _fail(str(exc)) from exc
    viewer.close()
    metrics["input"] = str(input)
    _print_mapclass(metrics, f"map classification of {input}")
    console.print(f"wrote {out}/map_classified.las and one LAS per class")
    if json_path is not None:
        _write_json(json_path, metrics, cfg)


class SceneKind(str, Enum):
    urban = "urban"
    forest = "forest"


class SensorKind(str, Enum):
    hdl64 = "hdl64"
    vlp16 = "vlp16"
    profiler_urban = "profiler-urban"
    profiler_backpack = "profiler-backpack"


@app.command()
def simulate(
    out: Path = typer.Option(..., help="output directory (the simulator's dataset format)"),
    scene: SceneKind = typer.Option(SceneKind.urban, help="procedural scene"),
    sensor: SensorKind = typer.Option(SensorKind.hdl64, help="simulated sensor"),
    frames: int = typer.Option(200, min=1, help="frames (sweeps, or blocks of scan lines for profilers)"),
    seed: int = typer.Option(0, help="scene, trajectory and noise seed: same seed, same bytes"),
    outlier_rate: float = typer.Option(0.0, min=0.0, max=1.0, help="background-illumination outliers per slot"),
    wind: float = typer.Option(0.0, min=0.0, help="foliage sway amplitude (m)"),
    speed: float | None = typer.Option(None, help="platform speed (m/s); default 8.33 vehicle, 1.3 walking"),
    kitti: Path | None = typer.Option(None, help="also export KITTI/SemanticKITTI here (spinning sensors)"),
) -> None:
    """Simulate a drive or walk with per-slot ground truth (Open3D ray casting)."""
    from data_tools.sim.dataset import SimSequence, export_kitti, write_sequence
    from data_tools.sim.simulator import NoiseConfig, SimConfig, Simulator

    try:
        cfg = SimConfig(
            scene=scene.value,
            sensor=sensor.value,
            frames=frames,
            seed=seed,
            wind=wind,
            speed=speed,
            noise=NoiseConfig(outlier_rate=outlier_rate),
        )
        sim = Simulator(cfg)
    except ValueError as exc:
        raise _fail(str(exc)) from exc
    with _progress() as progress:
        task = progress.add_task(f"simulating {scene.value}/{sensor.value}", total=frames)
        write_sequence(sim, out, on_frame=lambda _f: progress.advance(task))
        if kitti is not None:
            seq = SimSequence(out)
            task2 = progress.add_task("KITTI export", total=len(seq))
            export_kitti(seq, kitti, on_frame=lambda _i: progress.advance(task2))
    console.print(f"wrote {frames} frames to {out}" + (f" and a KITTI export to {kitti}" if kitti else ""))


@app.command()
def bench(
    kitti: Path = typer.Option(DEFAULT_KITTI, help="KITTI directory for the real-data figures (skipped if absent)"),
    json_path: Path | None = typer.Option(None, "--json", help="write the bench JSON here"),
) -> None:
    """Throughput of each stage on its reference input (single process)."""
    from prc_slam.benchmark import run_bench

    if not (kitti / "velodyne").is_dir():
        console.print(f"[yellow]{kitti} not found: KITTI figures skipped[/yellow]")
    results = run_bench(kitti if (kitti / "velodyne").is_dir() else None)
    table = Table(title="prc-slam bench")
    table.add_column("stage")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for stage, figures in results.items():
        for key, value in figures.items():
            table.add_row(stage, key, f"{value:,.3f}" if isinstance(value, float) else str(value))
    Console().print(table)
    if json_path is not None:
        _write_json(json_path, results)


@app.command()
def demo(
    out: Path = typer.Option(Path("out/demo"), help="output directory"),
    frames: int = typer.Option(150, min=2, help="frames of the simulated hdl64 urban drive"),
    seed: int = typer.Option(0, help="scene and noise seed"),
    connect: str | None = CONNECT_OPT,
    serve_web: bool = SERVE_OPT,
    log_every: int = EVERY_OPT,
    map_voxel: float = MAP_VOXEL_OPT,
) -> None:
    """Simulate an urban drive (cached after the first run), score PRC against its ground truth,
    and compare raw vs PRC-filtered KISS-ICP odometry (report, metrics, trajectories, plots)."""
    from data_tools.sim.dataset import SimSequence, write_sequence
    from data_tools.sim.simulator import NoiseConfig, SimConfig, Simulator
    from data_tools.trajectory_io import write_kitti_poses, write_tum_poses
    from prc_slam.classify_run import run_classification
    from prc_slam.odometry.compare import run_compare
    from prc_slam.report import write_compare_outputs

    sim_cfg = SimConfig(scene="urban", sensor="hdl64", frames=frames, seed=seed, noise=NoiseConfig(outlier_rate=0.01))
    root = out / f"sim_urban_hdl64_{frames}_seed{seed}"
    cached = (root / "sim.json").is_file() and SimSequence(root).config == sim_cfg
    cfg = Config(prc=PRCConfig.preset("multibeam"))
    with _progress() as progress:
        if not cached:
            task = progress.add_task("simulating the urban drive", total=frames)
            write_sequence(Simulator(sim_cfg), root, on_frame=lambda _f: progress.advance(task))
        seq = SimSequence(root)
        task = progress.add_task("PRC", total=len(seq))
        prc_metrics = run_classification(iter(seq), cfg.prc, on_frame=lambda _f: progress.advance(task))
        task = progress.add_task("odometry raw | prc", total=len(seq))
        rrd = out.with_suffix(".rrd")
        viewer = Viewer(rrd, connect, serve_web, log_every, map_voxel=map_voxel)

        def on_frame(record) -> None:
            progress.advance(task)
            viewer.sink.log_record(record, gt_pose=record.frame.scan.gt_pose)

        result = run_compare(iter(seq), cfg, on_frame=on_frame)
        viewer.close()
    console.print(f"simulated drive: {root}" + (" (cached)" if cached else ""))
    _report(prc_metrics, "PRC (multibeam setting) on the simulated urban drive, 1 % outliers")
    _write_json(out / "prc_metrics.json", prc_metrics)
    metrics = write_compare_outputs(
        result, cfg, out, f"Raw vs PRC-filtered KISS-ICP on {root.name}", write_kitti_poses, write_tum_poses
    )
    print_variant_table(metrics, "KISS-ICP: raw vs PRC-filtered")
    console.print(f"report: {out / 'report.md'}  plots: {out / 'trajectories.png'}")


if __name__ == "__main__":  # pragma: no cover
    app()
