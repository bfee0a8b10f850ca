"""Out-of-core classification of maps larger than memory (paper 004, Sec. 5: "Large point
clouds are tiled into data chunks, which can be processed out-of-core").

Pass 1 streams the input in chunks and spills every point, with its index in the input, into
the file of its square x-y tile. Pass 2 classifies one tile at a time together with the points
of the neighbouring tiles that lie within ``margin`` of it, and keeps the labels of the tile's
own points. Memory is bounded by the densest tile and its margin, not by the map.
"""

from __future__ import annotations

import tempfile
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam import labels as L
from prc_slam.mapclass.classify import DensityWarning, MapClassConfig, MapResult, classify_map

_ROW = np.dtype([("xyz", "<f8", 3), ("index", "<i8")])


def _spill(chunks: Iterable[np.ndarray], tile: float, workdir: Path) -> tuple[dict[tuple[int, int], Path], int, int]:
    """Write the points of every tile to ``workdir``; returns the tile files, the point count
    and the count of non-finite points (they get ``no_return`` and no tile)."""
    files: dict[tuple[int, int], Path] = {}
    n = bad = 0
    for chunk in chunks:
        pts = np.asarray(chunk, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"point chunks must be (N, 3), got {pts.shape}")
        index = np.arange(n, n + len(pts))
        n += len(pts)
        ok = np.isfinite(pts).all(axis=1)
        bad += int((~ok).sum())
        pts, index = pts[ok], index[ok]
        keys = np.floor(pts[:, :2] / tile).astype(np.int64)
        order = np.lexsort((keys[:, 1], keys[:, 0]))
        keys, pts, index = keys[order], pts[order], index[order]
        cut = np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1
        for lo, hi in zip(np.r_[0, cut], np.r_[cut, len(keys)], strict=True):
            if hi <= lo:
                continue
            key = (int(keys[lo, 0]), int(keys[lo, 1]))
            path = files.setdefault(key, workdir / f"tile_{key[0]}_{key[1]}.bin")
            rows = np.empty(hi - lo, dtype=_ROW)
            rows["xyz"], rows["index"] = pts[lo:hi], index[lo:hi]
            with path.open("ab") as f:
                rows.tofile(f)
    return files, n, bad


def classify_tiled(
    chunks: Iterable[np.ndarray],
    config: MapClassConfig | None = None,
    tile: float = 40.0,
    margin: float = 6.0,
    workdir: str | Path | None = None,
    labels_out: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
    details: bool = False,
):
    """Classify a cloud given as chunks of points, tile by tile.

    Parameters
    ----------
    chunks : iterable of float (n_i, 3)
        The cloud in input order (e.g. a LAS file read in chunks).
    config : MapClassConfig, optional
    tile : float
        Tile side (m).
    margin : float
        Context (m) around each tile classified with it; must exceed the reach of the rules
        (3 m building growth, segment extents) for borders not to change labels.
    workdir : path, optional
        Where the tile files go (a temporary directory by default; removed afterwards).
    labels_out : uint8 array, optional
        Destination of the labels (e.g. an ``np.memmap``), sized to the cloud; allocated when
        None.
    progress : callable(done, total), optional
        Called after every tile.

    Returns
    -------
    labels : uint8 (N,)
        One code per input point, in input order (``no_return`` for non-finite points).
    seconds : dict
        Summed stage times over the tiles.
    density : dict
        Only with ``details``: :func:`density_summary` over the tiles (each tile takes its own
        relative threshold and sizes); one :class:`DensityWarning` sums up the tiles' messages.
    """
    if tile <= 0 or margin < 0:
        raise ValueError(f"tile must be > 0 and margin >= 0, got {tile}, {margin}")
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        files, n, _ = _spill(chunks, tile, Path(tmp))
        labels = np.full(n, L.NO_RETURN, np.uint8) if labels_out is None else labels_out
        if len(labels) != n:
            raise ValueError(f"labels_out holds {len(labels)} entries for {n} points")
        labels[:] = L.NO_RETURN
        seconds: dict[str, float] = {}
        results: list[MapResult] = []
        for done, key in enumerate(sorted(files), start=1):
            own, points = tile_points(files, key, tile, margin)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DensityWarning)  # summed up below
                result = classify_map(points, config)
            labels[own["index"]] = result.labels[: len(own)]
            results.append(_light(result, len(own)))
            for k, v in result.seconds.items():
                seconds[k] = seconds.get(k, 0.0) + v
            if progress is not None:
                progress(done, len(files))
    density = density_summary(results)
    if density["messages"]:
        warnings.warn(
            f"{len(density['messages'])} of {len(results)} tiles: " + density["messages"][0],
            DensityWarning,
            stacklevel=2,
        )
    return (labels, seconds, density) if details else (labels, seconds)


def tile_points(
    files: dict[tuple[int, int], Path], key: tuple[int, int], tile: float, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """The tile's own rows (``index``, ``xyz``) and the points classified with it: its own
    points first, then those of the neighbouring tiles within ``margin``."""
    own = np.fromfile(files[key], dtype=_ROW)
    lo = np.array(key, dtype=np.float64) * tile - margin
    hi = lo + tile + 2 * margin
    reach = int(np.ceil(margin / tile))
    parts = [own["xyz"]]
    for dx in range(-reach, reach + 1):
        for dy in range(-reach, reach + 1):
            other = files.get((key[0] + dx, key[1] + dy))
            if (dx or dy) and other is not None:
                xyz = np.fromfile(other, dtype=_ROW)["xyz"]
                inside = np.all((xyz[:, :2] >= lo) & (xyz[:, :2] < hi), axis=1)
                parts.append(xyz[inside])
    return own, np.concatenate(parts)


def _light(result: MapResult, n_own: int) -> MapResult:
    """A tile's result without its per-point arrays (kept for the summary); ``below_share`` is
    weighted by the tile's own points."""
    return MapResult(
        np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros(n_own), np.zeros(0), {}, result.nonfinite,
        result.scale, result.below_share, result.messages,
    )  # fmt: skip


def density_summary(results: list[MapResult]) -> dict[str, Any]:
    """Surface density, sizes and thresholds used (min / median / max over tiles), the share
    of points under the threshold, the shares of the tiles whose ground took the terrain-relative
    tests (:class:`~prc_slam.mapclass.classify.GroundParams`) and whose vegetation was their
    foliage alone (wooded: ``VegetationParams.canopy_share``), and the messages."""
    scales = [r.scale for r in results if r.scale is not None]
    weights = np.array([len(r.density) for r in results], dtype=np.float64)
    out: dict[str, Any] = {"relative": bool(scales[0].relative) if scales else None}
    for key in ("rho", "density_voxel", "normal_voxel", "ground_cell", "threshold"):
        vals = np.array([getattr(s, key) for s in scales], dtype=np.float64)
        if len(vals):
            out[key] = {"min": float(vals.min()), "median": float(np.median(vals)), "max": float(vals.max())}
    shares = np.array([r.below_share for r in results])
    out["below_threshold_share"] = float((shares * weights).sum() / weights.sum()) if weights.sum() else 0.0
    pieces = [r.choices for r in results if r.choices]
    out["terrain_ground_share"] = float(np.mean([bool(c.get("terrain")) for c in pieces])) if pieces else 0.0
    out["canopy_share"] = float(np.mean(["canopy" in c for c in pieces])) if pieces else 0.0  # wooded pieces
    out["raised_ground_cells"] = int(sum(c.get("raised_cells", 0) for c in pieces))
    out["messages"] = [m for r in results for m in r.messages]
    return out


def array_chunks(points: np.ndarray, size: int = 1_000_000) -> Iterable[np.ndarray]:
    """An in-memory cloud as chunks for :func:`classify_tiled`."""
    for i in range(0, len(points), size):
        yield points[i : i + size]
