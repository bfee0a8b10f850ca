"""Constructed sweeps of a spinning multi-beam sensor: rays cast against a flat road and
axis-aligned boxes (car bodies, walls), with a window band that returns nothing, so that every
expected label is known by construction."""

from __future__ import annotations

import numpy as np

from prc_slam.scan import Scan, SpinningSensor

MOUNT = 1.73  # sensor above the road


def sensor(beams: int = 64, cols: int = 1024) -> SpinningSensor:
    return SpinningSensor.create(np.radians(np.linspace(2.0, -24.8, beams)), cols)


def ray_boxes(dirs: np.ndarray, boxes: list[tuple]) -> tuple[np.ndarray, np.ndarray]:
    """Range of the first hit of every ray from the origin: the road plane z = -MOUNT and
    axis-aligned boxes ``(lo xyz, hi xyz, id)``; returns ranges (0 = nothing within 80 m) and
    the id of what was hit (0 road or nothing)."""
    d = dirs.reshape(-1, 3)
    best = np.where(d[:, 2] < -1e-9, -MOUNT / np.minimum(d[:, 2], -1e-9), np.inf)
    ident = np.zeros(len(d), np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo, hi, k in boxes:
            t1 = (np.asarray(lo)[None, :] - 0.0) / d
            t2 = (np.asarray(hi)[None, :] - 0.0) / d
            tmin = np.nanmax(np.minimum(t1, t2), axis=1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tmax >= tmin) & (tmin > 0) & (tmin < best)
            best = np.where(hit, tmin, best)
            ident = np.where(hit, k, ident)
    best = np.where(best < 80.0, best, 0.0)
    return best.reshape(dirs.shape[:2]), ident.reshape(dirs.shape[:2])


def car_boxes(x: float, y: float, length: float = 4.4, width: float = 1.8, k: int = 1) -> list[tuple]:
    """A car as boxes: body 0.3-0.95 m, a window band 0.95-1.3 m (glass: hits are dropped),
    roof 1.3-1.5 m set in by 0.2 m; wheels carry it to the road."""
    z0 = -MOUNT
    return [
        ((x, y, z0 + 0.3), (x + length, y + width, z0 + 0.95), k),
        ((x + 0.6, y + 0.2, z0 + 0.95), (x + length - 0.8, y + width - 0.2, z0 + 1.3), -k),  # glass
        ((x + 0.6, y + 0.2, z0 + 1.3), (x + length - 0.8, y + width - 0.2, z0 + 1.5), k),
        ((x + 0.5, y, z0), (x + 1.0, y + width, z0 + 0.3), k),  # wheels
        ((x + length - 1.0, y, z0), (x + length - 0.5, y + width, z0 + 0.3), k),
    ]


def sweep(objects: list[tuple], beams: int = 64, cols: int = 1024, noise: float = 0.01, seed: int = 0):
    model = sensor(beams, cols)
    ranges, ident = ray_boxes(model.directions(), objects)
    glass = ident < 0
    ranges[glass] = 0.0
    ident[glass] = 0
    rng = np.random.default_rng(seed)
    ranges = np.where(ranges > 0, ranges + rng.normal(0, noise, ranges.shape), 0.0).astype(np.float32)
    return Scan(ranges, model), ident
