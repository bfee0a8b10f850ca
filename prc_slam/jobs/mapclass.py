"""The ``mapclass`` job: classification after registration (paper 004) of a cloud file or of a
sequence accumulated at its poses, with per-class LAS files, scores and the map in Rerun."""

from __future__ import annotations

import logging
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam import labels as L
from prc_slam import mapclass
from prc_slam.config import Config
from prc_slam.evaluation.metrics import ConfusionAccumulator, objects_found
from prc_slam.jobs.common import Viewer
from prc_slam.jobs.progress import Reporter
from prc_slam.mapclass import MapClassConfig
from prc_slam.mapclass.tiles import classify_tiled, density_summary

log = logging.getLogger("prc_slam.mapclass")

#: paper 004's classes, scored point by point (forest mode: stems are trunk)
MAP_CLASSES = [L.GROUND, L.BUILDING, L.VEHICLE, L.POLE, L.VEGETATION]
FOREST_CLASSES = [L.GROUND, L.BUILDING, L.VEHICLE, L.TRUNK, L.VEGETATION]
#: reference codes folded into paper 004's classes before scoring (curbs are ground; the paper
#: has no stem class: trunks belong to the vegetation outside forest mode)
MAP_REFERENCE = {
    L.CURB: L.GROUND,
    L.TRUNK: L.VEGETATION,
    3: L.VEGETATION,
    4: L.VEGETATION,
    11: L.GROUND,
    18: L.NOISE,
    20: L.GROUND,
}
#: (ASPRS low and medium vegetation, 3 and 4, are vegetation, road surface and ignored ground, 11
#: and 20, are ground and high noise, 18, is noise, so a public tile's own classes can serve as the
#: reference)
#: a reference object counts as present with this many map points, as found with this share
OBJECT_MIN_POINTS, OBJECT_SHARE = 100, 0.5
#: clouds up to this size are classified in one piece unless a tile size is given
UNTILED_MAX_POINTS = 12_000_000


def fold_reference(reference: np.ndarray, mode: str = "urban") -> np.ndarray:
    """Reference codes folded into the classes map classification gives (forest mode keeps
    trunks)."""
    out = np.asarray(reference, dtype=np.uint8).copy()
    for src, dst in MAP_REFERENCE.items():
        if not (mode == "forest" and src == L.TRUNK):
            out[out == src] = dst
    return out


def score_map(
    labels: np.ndarray, reference: np.ndarray, instance: np.ndarray | None = None, mode: str | None = None
) -> dict[str, Any]:
    """Per-class precision / recall / F1 for paper 004's classes (forest mode: with trunk; by
    default forest when ``labels`` hold trunks, which only forest mode gives), the confusion
    matrix, object counts (found / present) for vehicles and poles when instances are known,
    and ``noise_share``: points labelled noise among the reference's non-noise points."""
    labels = np.asarray(labels)
    if mode is None:
        mode = "forest" if (labels == L.TRUNK).any() else "urban"
    if len(labels) != len(reference):
        raise ValueError(f"{len(labels)} labels for {len(reference)} reference codes")
    ref = fold_reference(reference, mode)
    confusion = ConfusionAccumulator()
    confusion.add(ref, labels)
    classes = FOREST_CLASSES if mode == "forest" else MAP_CLASSES
    out: dict[str, Any] = {"per_class": confusion.per_class(classes), "confusion": confusion.to_json()}
    real = (ref != L.NOISE) & (ref != L.NO_RETURN)
    out["noise_share"] = float(np.mean(labels[real] == L.NOISE)) if real.any() else None
    if instance is not None:
        out["objects"] = {}
        for code in (L.VEHICLE, L.POLE):
            found, present = objects_found(reference, instance, labels, code, OBJECT_MIN_POINTS, OBJECT_SHARE)
            out["objects"][L.CODE_TO_NAME[code]] = {"found": found, "present": present}
    return out


def run_mapclass(
    chunks: Callable[[], Iterable[np.ndarray]],
    n_points: int,
    config: MapClassConfig,
    tile: float | None = None,
    margin: float = 6.0,
    labels_out: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
    tiler: Callable[..., Any] | None = None,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Classify a cloud given as chunks, in one piece or tile by tile.

    Parameters
    ----------
    chunks : callable returning an iterable of float (n, 3)
        The cloud in input order (called once).
    n_points : int
        Its size (decides tiling when ``tile`` is None).
    tile : float, optional
        Tile side (m); 0 forces one piece; None tiles at 40 m above ``UNTILED_MAX_POINTS``.
    tiler : callable, optional
        Replaces :func:`classify_tiled` (same arguments and returns), e.g.
        :func:`prc_slam.jobs.distributed.classify_tiled_distributed` bound to a Dask client.

    Returns
    -------
    labels : uint8 (N,)
    metrics : dict
        ``points``, ``seconds``, ``points_per_s``, ``seconds_per_stage``, ``counts``, ``tile``.
    """
    if tile is None:
        tile = 40.0 if n_points > UNTILED_MAX_POINTS else 0.0
    t0 = time.perf_counter()
    if tile > 0:
        labels, seconds, density = (tiler or classify_tiled)(
            chunks(), config, tile, margin, labels_out=labels_out, progress=progress, details=True
        )
    else:
        parts = list(chunks())
        points = np.concatenate(parts) if parts else np.zeros((0, 3))
        result = mapclass.classify_map(points, config)
        labels, seconds = result.labels, result.seconds
        density = density_summary([result])
        if labels_out is not None:
            labels_out[:] = labels
            labels = labels_out
        if progress is not None:
            progress(1, 1)
    wall = time.perf_counter() - t0
    counts = np.bincount(labels, minlength=256)
    metrics: dict[str, Any] = {
        "points": len(labels),
        "seconds": wall,
        "points_per_s": len(labels) / wall if wall > 0 else None,
        "seconds_per_stage": seconds,
        "counts": {L.CODE_TO_NAME.get(int(c), f"code_{c}"): int(counts[c]) for c in np.flatnonzero(counts)},
        "tile": tile,
        "margin": margin if tile > 0 else None,
        "density": density,
        "messages": density.pop("messages", []),
    }
    return labels, metrics


def prc_agreement(prc_labels: np.ndarray, map_labels: np.ndarray) -> dict[str, Any]:
    """Point-by-point agreement of preregistration labels with the map's classification (the
    map is the reference, as the PRC paper compares itself with classification after
    registration): confusion matrix and per-class scores of PRC's classes."""
    confusion = ConfusionAccumulator()
    confusion.add(map_labels, prc_labels)
    codes = [
        c
        for c in (L.GROUND, L.BUILDING, L.VEGETATION, L.NOISE)
        if confusion.counts[c].sum() or confusion.counts[:, c].sum()
    ]
    return {"per_class": confusion.per_class(codes), "confusion": confusion.to_json()}


def map_from_dataset(
    dataset, n: int, every: int, poses: Path | np.ndarray | None, prc: dict[int, np.ndarray] | None = None
):
    """Accumulate every ``every``-th of the first ``n`` frames at the given poses (an array, a
    KITTI pose file, or None for the sequence's ground truth), carrying reference labels and
    instances when present and PRC labels for the frames in ``prc``."""
    from data_tools.formats.trajectory_io import read_pose_file
    from prc_slam.mapclass import accumulate

    source = "ground truth" if poses is None else str(poses) if isinstance(poses, Path) else "the estimate"
    times = getattr(dataset, "times", None)
    if isinstance(poses, Path):
        poses = read_pose_file(poses, None if times is None else np.asarray(times, dtype=float)[:n])
    elif poses is None:
        poses = getattr(dataset, "poses", None)
    if poses is None:
        raise ValueError("--poses: the input has no ground-truth poses; give a pose file (KITTI or TUM)")
    if len(poses) < n:
        raise ValueError(f"{source}: {len(poses)} poses for {n} frames")
    if source not in ("ground truth", "the estimate"):
        if len(poses) > n:
            log.warning("%s: %d poses for %d frames: the first %d are used, in order", source, len(poses), n, n)
        warn_unless_z_up(np.asarray(poses)[:n], source)
    times = np.arange(n) * 0.1 if times is None else np.asarray(times, dtype=float)

    def frames():
        # every frame carries every attribute, with a mask of the frames that have it (frames
        # without labels, e.g. SemanticKITTI 00 beyond frame 2, took no part: the attribute was
        # then shorter than the map, '496488 labels for 249146 reference codes')
        for i in range(0, n, every):
            scan = dataset[i]
            size = scan.n_points
            ref = scan.reference_labels()
            inst = scan.per_point(scan.gt_instance) if ref is not None and scan.gt_instance is not None else None
            extra = {
                "reference": np.zeros(size, np.uint8) if ref is None else ref,
                "reference_known": np.full(size, ref is not None),
                "instance": np.zeros(size, np.uint32) if inst is None else np.asarray(inst, np.uint32),
                "instance_known": np.full(size, inst is not None),
            }
            if prc is not None:
                own = prc.get(i)
                extra["prc"] = np.zeros(size, np.uint8) if own is None else own
                extra["prc_known"] = np.full(size, own is not None)
            yield i, scan, extra

    cloud = accumulate(frames(), np.asarray(poses)[:n], times[:n])
    for name in ("reference", "instance", "prc"):
        known = cloud.attributes.pop(f"{name}_known", None)
        if known is None or not known.any():
            cloud.attributes.pop(name, None)
        elif name != "instance" and not known.all():  # a missing instance is 0 (none)
            cloud.attributes[f"{name}_known"] = known
    return cloud


def warn_unless_z_up(poses: np.ndarray, source: str) -> bool:
    """Warn when the sensor's path climbs more than it travels horizontally (over 2 m of path):
    poses in a frame whose z is not up, as KITTI's own ``poses.txt`` (camera 0: y down, z forward),
    stack the sweeps on top of each other and classify a road as buildings. Returns whether it
    warned."""
    steps = np.diff(np.asarray(poses, dtype=np.float64)[:, :3, 3], axis=0)
    if len(steps) == 0:
        return False
    vertical = float(np.abs(steps[:, 2]).sum())
    horizontal = float(np.hypot(steps[:, 0], steps[:, 1]).sum())
    if vertical + horizontal < 2.0 or vertical <= horizontal:
        return False
    log.warning(
        "%s: the poses climb %.1f m and move %.1f m horizontally: is z up in their frame? Map classification "
        "needs z up; KITTI's poses.txt is in camera 0's frame (y down, z forward): give LiDAR poses (prc-slam "
        "odometry --poses-out writes them) or leave --poses out to use the sequence's own ground truth",
        source,
        vertical,
        horizontal,
    )
    return True


def _known(values: np.ndarray | None, known: np.ndarray | None) -> np.ndarray | None:
    """``values`` where ``known`` (all of them when ``known`` is None)."""
    if values is None or known is None:
        return values
    return np.asarray(values)[known]


def classify_map(
    points_source: Callable[[], Iterator[np.ndarray]],
    n_points: int,
    cfg: Config,
    out: Path,
    tile: float | None,
    margin: float,
    reference=None,
    instance=None,
    prc=None,
    viewer: Viewer | None = None,
    reporter: Reporter | None = None,
    laz: bool = False,
    tiler: Callable[..., Any] | None = None,
    reference_known: np.ndarray | None = None,
    prc_known: np.ndarray | None = None,
    crs: list | None = None,
    grid: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, Any]:
    """Classify, write the per-class LAS (``laz``: LAZ) files, score; returns the metrics. Tiled
    runs keep the labels in a memory-mapped scratch file (one byte per point), so the map never
    has to fit. The density messages (Sec. 3.1 threshold) are logged as warnings.

    ``reference_known`` / ``prc_known``: the points that have a reference / PRC label (a map
    accumulated from frames of which only some are labelled); the scores count only those
    (``scored_points``, ``prc_points``). ``crs``: the input's CRS records, copied to every file;
    ``grid``: its LAS ``(scales, offsets)``, kept in every file."""
    from data_tools.formats.writers import ClassSplitWriter
    from prc_slam.mapclass.classify import DensityWarning

    out.mkdir(parents=True, exist_ok=True)
    tiled = tile > 0 if tile is not None else n_points > UNTILED_MAX_POINTS
    task = None if reporter is None else reporter.task("map classification (tiles)")

    def progress(done: int, total: int) -> None:
        if task is not None:
            task.total = total
            task.advance(done - task.done)

    with tempfile.TemporaryDirectory(dir=out) as scratch:
        store = np.memmap(Path(scratch) / "labels.u8", np.uint8, "w+", shape=(max(n_points, 1),)) if tiled else None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DensityWarning)  # logged below, once
            labels, metrics = run_mapclass(
                points_source, n_points, cfg.mapclass, tile, margin,
                labels_out=None if store is None else store[:n_points], progress=progress, tiler=tiler,
            )  # fmt: skip
        for message in metrics.get("messages", []):
            log.warning(message)
        with ClassSplitWriter(
            out, combined="map_classified.laz" if laz else "map_classified.las", crs=crs, grid=grid
        ) as writer:
            start = 0
            for part, chunk in enumerate(points_source()):
                writer.write(chunk, labels[start : start + len(chunk)])
                if viewer is not None and viewer.sink is not None:
                    viewer.sink.log_map(chunk, labels[start : start + len(chunk)], part)
                start += len(chunk)
        labels = np.array(labels) if reference is not None or prc is not None else None
        del store
    metrics["files"] = {k: str(v) for k, v in writer.paths.items()}
    metrics["points_not_written"] = writer.skipped  # no finite coordinates: LAS cannot store them
    if reference is not None:
        metrics.update(
            score_map(
                _known(labels, reference_known), _known(reference, reference_known), _known(instance, reference_known)
            )
        )
        if reference_known is not None:
            metrics["scored_points"] = int(np.count_nonzero(reference_known))
    if prc is not None:
        metrics["prc_vs_map"] = prc_agreement(_known(prc, prc_known), _known(labels, prc_known))
        if prc_known is not None:
            metrics["prc_vs_map"]["points"] = int(np.count_nonzero(prc_known))
    return metrics


#: ASPRS classes of a tile's own classification (LAS 1.4 R15, Table 17) that paper 004's classes
#: have no counterpart for, by name
ASPRS_OTHER = {
    8: "model key-point",
    9: "water",
    10: "rail",
    12: "overlap",
    13: "wire guard",
    14: "wire conductor",
    15: "transmission tower",
    16: "wire connector",
    17: "bridge deck",
    19: "overhead structure",
    21: "snow",
    22: "temporal exclusion",
}


def warn_unscored_reference(path: Path, reference: np.ndarray) -> list[int]:
    """Warn, with their counts, of the classes in a LAS file's own classification that map
    classification has no class for (ASPRS water, rail, wires, bridge deck, ...; user codes):
    every such point counts against the precision of the class it is given. Codes 64 and up are
    this package's (trunk, vehicle, curb, pole, ...) and are taken as such: in another producer's
    file they are user classes that mean something else. Returns the codes warned of."""
    from prc_slam import labels as L

    counts = np.bincount(np.asarray(reference, np.uint8), minlength=256)
    known = {L.NO_RETURN, L.UNCLASSIFIED, *MAP_REFERENCE, *MAP_REFERENCE.values(), *L.CODE_TO_NAME}
    other = [int(c) for c in np.flatnonzero(counts) if int(c) not in known]
    if other:
        log.warning(
            "%s: its own classes include %s, which map classification has no class for: those points count "
            "against the precision of the class each is given",
            path,
            ", ".join(f"{c} ({ASPRS_OTHER.get(c, 'user or reserved')}: {counts[c]:,} points)" for c in other),
        )
    return other


def check_spread(path: Path, chunks: Iterator[np.ndarray], count: int | None = None) -> None:
    """Raise :class:`~data_tools.errors.DataError` for a cloud with no point of finite coordinates
    or whose points all lie at one position: there is nothing to classify (before, such a cloud
    came out 'ground' or wrote no file while saying it had). ``count``: the number of points, when
    ``chunks`` are only their bounds (a LAS header's)."""
    from data_tools.errors import DataError

    lo, hi, seen = np.full(3, np.inf), np.full(3, -np.inf), 0
    for chunk in chunks:
        good = chunk[np.isfinite(chunk).all(axis=1)]
        if len(good):
            lo, hi = np.minimum(lo, good.min(axis=0)), np.maximum(hi, good.max(axis=0))
            seen += len(good)
    if not seen:
        raise DataError(f"{path}: no point has finite coordinates: nothing to classify")
    seen = seen if count is None else count
    if np.array_equal(lo, hi):
        where = f"({lo[0]:g}, {lo[1]:g}, {lo[2]:g})"
        raise DataError(
            f"{path}: "
            + (f"a single point {where}" if seen == 1 else f"all {seen:,} points lie at one position {where}")
            + ": nothing to classify"
        )


def refuse_sequence_options(input: Path, poses, max_frames, every: int, **open_options: Any) -> None:
    """Raise :class:`~data_tools.errors.DataError` when options that only a sequence takes
    (``--poses``, ``--every``, ``--max-frames``, the readers' options) are given with one cloud
    file: ``mapclass map.las --poses p.txt --every 3`` classified the cloud and ignored them. (The
    CLI calls this; a batch applies its options to every input, clouds and sequences alike.)"""
    from data_tools.errors import DataError

    given = {"--poses": poses, "--max-frames": max_frames, "--every": every if every != 1 else None}
    given.update({"--" + k.replace("_method", "").replace("_", "-"): v for k, v in open_options.items()})
    named = [k for k, v in given.items() if v is not None]
    if named:
        raise DataError(
            f"{', '.join(named)}: for a sequence of sweeps; {input} is one cloud, classified as it is stored"
        )


def mapclass_job(
    input: Path,
    cfg: Config,
    out: Path,
    *,
    tile: float | None = None,
    margin: float = 6.0,
    fmt: str | None = None,
    max_frames: int | None = None,
    every: int = 1,
    poses: Path | None = None,
    viewer: Viewer | None = None,
    reporter: Reporter | None = None,
    note: Callable[[str], None] | None = None,
    laz: bool = False,
    reference: bool | None = None,
    tiler: Callable[..., Any] | None = None,
    **open_options: Any,
) -> dict[str, Any]:
    """Classify a cloud file, or a sequence accumulated at its poses (ground truth or ``poses``).

    A LAS/LAZ file that carries classes of its own (beyond 0 and 1) is scored against them
    (``reference=None``: when it has them; True: required; False: never)."""
    from data_tools.errors import DataError
    from data_tools.formats.clouds import cloud_chunks, cloud_classes, cloud_crs, cloud_grid, cloud_size, is_cloud_file
    from data_tools.formats.laz import laz_backend
    from prc_slam.jobs.common import open_input
    from prc_slam.mapclass.tiles import array_chunks

    viewer = viewer or Viewer()
    if is_cloud_file(input):
        own = None if reference is False else cloud_classes(input)
        if reference and own is None:
            raise ValueError(f"--reference: {input} carries no classes to score against")
        ref, inst, scored = own if own is not None else (None, None, None)
        if ref is not None:
            warn_unscored_reference(input, ref if scored is None else ref[scored])
        size = cloud_size(input)
        if size == 0:
            raise DataError(f"{input}: the cloud holds no points")
        if input.suffix.lower() in (".las", ".laz"):  # LAS stores finite coordinates and their bounds
            import laspy

            with laspy.open(input, laz_backend=laz_backend(input)) as f:
                check_spread(input, iter([np.array([f.header.mins, f.header.maxs])]), size)
        else:
            check_spread(input, cloud_chunks(input))
        metrics = classify_map(
            lambda: cloud_chunks(input), size, cfg, out, tile, margin, ref, inst, viewer=viewer,
            reporter=reporter, laz=laz, tiler=tiler, crs=cloud_crs(input), grid=cloud_grid(input),
            reference_known=scored,
        )  # fmt: skip
        if scored is not None:
            metrics["scored_on"] = "points not withheld (LAS withheld flag)"
        if own is not None and note is not None:
            skipped = 0 if scored is None else int(np.count_nonzero(~scored))
            note(
                f"scored against the classes stored in {input}"
                + (f" ({skipped:,} withheld points not scored)" if skipped else "")
            )
    else:
        if input.is_file() and fmt is None:
            from data_tools.datasets import detect_format
            from data_tools.formats.clouds import CLOUD_SUFFIXES

            try:
                detect_format(input)
            except DataError as exc:
                if "unknown input format" not in str(exc):
                    raise
                raise DataError(
                    f"{input}: unknown cloud format {input.suffix!r}: mapclass reads one cloud file "
                    f"({', '.join(CLOUD_SUFFIXES)}, .npz) or a sequence of sweeps (as classify does)"
                ) from exc
        if input.is_dir() and fmt is None:
            suffixes = [f.suffix.lower() for f in input.iterdir() if f.is_file()]
            tiles = sorted(f for f in input.iterdir() if f.is_file() and f.suffix.lower() in (".las", ".laz"))
            if tiles and not any(x in suffixes for x in (".pcd", ".ply", ".bin", ".npz")):
                raise DataError(
                    f"{input}: a folder of {len(tiles)} LAS/LAZ files: mapclass classifies one cloud file; give "
                    f"the tiles one at a time (e.g. {tiles[0]}) or merged into one"
                )
        dataset, n = open_input(input, fmt, max_frames, **open_options)
        cloud = map_from_dataset(dataset, n, every, poses)
        if note is not None:
            note(f"accumulated {len(cloud):,} points from {len(range(0, n, every))} frames")
        metrics = classify_map(
            lambda: array_chunks(cloud.points), len(cloud), cfg, out, tile, margin,
            cloud.attributes.get("reference"), cloud.attributes.get("instance"), viewer=viewer, reporter=reporter,
            laz=laz, tiler=tiler, reference_known=cloud.attributes.get("reference_known"),
        )  # fmt: skip
    viewer.close()
    metrics["input"] = str(input)
    return metrics


def compare_mapclass(
    input: Path,
    fmt: str | None,
    run,
    variant: str,
    every: int,
    prc_labels: dict,
    cfg: Config,
    out: Path,
    **open_options: Any,
) -> dict[str, Any]:
    """``compare --mapclass``: the map accumulated at ``variant``'s poses, classified after
    registration, and PRC's agreement with it."""
    from prc_slam.jobs.common import open_input
    from prc_slam.mapclass.tiles import array_chunks

    dataset, _ = open_input(input, fmt, **open_options)
    n = len(run.result.times)
    cloud = map_from_dataset(dataset, n, every, run.result.estimate_in_world(variant), prc_labels or None)
    mc = classify_map(
        lambda: array_chunks(cloud.points), len(cloud), cfg, out / "mapclass", None, 6.0,
        cloud.attributes.get("reference"), cloud.attributes.get("instance"), cloud.attributes.get("prc"),
        reference_known=cloud.attributes.get("reference_known"), prc_known=cloud.attributes.get("prc_known"),
    )  # fmt: skip
    mc["poses"] = variant
    mc["map_points"] = len(cloud)
    return mc
