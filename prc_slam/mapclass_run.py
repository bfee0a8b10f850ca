"""The ``mapclass`` job: classify a registered map (in memory or tiled), score it against
reference labels, and compare preregistration labels with it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from prc_slam import labels as L
from prc_slam.evaluation import ConfusionAccumulator, objects_found
from prc_slam.mapclass import MapClassConfig, classify_map
from prc_slam.mapclass.tiles import classify_tiled, density_summary

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
        result = classify_map(points, config)
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
