"""Small analytic range images for tests, benchmarks and the first demo.

:func:`profiler_block` ray-casts a tilted 2-D profiler moving along a street with a flat
road, two facades and bushes, with range noise, outliers and dropouts, and returns the range
image and the reference class of every slot. It is not the full simulator (that one casts
rays into triangle meshes); it is a reproducible, dependency-free input with ground truth.
"""

from __future__ import annotations

import numpy as np

from prc_slam import labels as L
from prc_slam.scan import ProfilerSensor, Scan


def profiler_block(
    k: int = 99,
    M: int = 2154,
    *,
    seed: int = 0,
    height: float = 2.5,
    street_half_width: float = 9.0,
    line_spacing: float = 0.17,
    range_sigma: float = 0.01,
    outlier_rate: float = 0.01,
    max_range: float = 80.0,
    row0: int = 0,
) -> Scan:
    """A ``k x M`` block of a profiler scanning a street (scan plane perpendicular to travel).

    Geometry per scan line (the y-z plane at x = line index * spacing): road ``z = -height``,
    facades at ``y = ±street_half_width``, bushes (random-range blobs) in front of the left
    facade every few metres; sky gives no return. Returns a Scan with ``gt_labels``.
    """
    rng = np.random.default_rng(seed)
    sensor = ProfilerSensor.create(k, M, angle0=0.0, line_spacing=line_spacing)
    theta = 2.0 * np.pi * np.arange(M) / M
    cy, sz = np.cos(theta), np.sin(theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_road = np.where(sz < -1e-6, -height / sz, np.inf)
        t_wall = np.where(np.abs(cy) > 1e-6, street_half_width / np.abs(cy), np.inf)
    base = np.minimum(t_road, t_wall)
    cls = np.where(t_road <= t_wall, L.GROUND, L.BUILDING).astype(np.uint8)
    ranges = np.broadcast_to(base, (k, M)).copy()
    gt = np.broadcast_to(cls, (k, M)).copy()
    x = (row0 + np.arange(k)) * line_spacing
    # bushes: in front of the left facade (cy < 0), 1-2.5 m tall, 2 m long every 6 m
    hit_y = ranges * cy[None, :]
    hit_z = ranges * sz[None, :]
    in_bush_x = (np.mod(x, 6.0) < 2.0)[:, None]
    bush_zone = in_bush_x & (hit_y < -street_half_width + 0.5) & (hit_z < -height + 2.0) & (gt == L.BUILDING)
    porous = rng.random((k, M)) < 0.8
    bush = bush_zone & porous
    depth = street_half_width - 1.5 + rng.random((k, M)) * 1.0
    ranges[bush] = (depth / np.abs(cy[None, :]).repeat(k, 0))[bush]
    gt[bush] = L.VEGETATION
    # sky and beyond max range: no return
    sky = ~np.isfinite(ranges) | (ranges > max_range)
    ranges[sky] = 0.0
    gt[sky] = L.NO_RETURN
    valid = ranges > 0
    ranges[valid] += rng.normal(0.0, range_sigma, valid.sum())
    dropout = valid & (rng.random((k, M)) < 0.01)
    ranges[dropout] = 0.0
    gt[dropout] = L.NO_RETURN
    outliers = valid & ~dropout & (rng.random((k, M)) < outlier_rate)
    ranges[outliers] = rng.uniform(0.5, max_range, outliers.sum())
    gt[outliers] = L.NOISE
    return Scan(ranges=ranges.astype(np.float32), sensor=sensor, gt_labels=gt, name=f"{row0:06d}", source="synthetic")
