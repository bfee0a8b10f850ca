"""Map clouds of known classes: an airborne-like scan of ground, one building and outliers."""

from __future__ import annotations

import numpy as np

from prc_slam import labels as L

RNG = np.random.default_rng(7)


def grid_plane(x0, x1, y0, y1, step, z=0.0, noise=0.0):
    """Points on a regular grid of ``step`` over ``[x0, x1) x [y0, y1)`` at height ``z``, with Gaussian
    height noise of ``noise`` m."""
    x, y = np.meshgrid(np.arange(x0, x1, step) + step / 2, np.arange(y0, y1, step) + step / 2, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), z + RNG.normal(0, noise, x.size) if noise else np.full(x.size, z)])


def airborne_like(density=2.0, seed=0):
    """A flat 60 x 60 m ground at ``density`` points/m^2 (jittered grid), a 20 x 12 x 8 m
    building seen from above (roof at that density, walls at a fifth of it) and isolated
    outliers 15-40 m above and 3-6 m below the ground."""
    rng = np.random.default_rng(seed)
    step = 1 / np.sqrt(density)
    g = grid_plane(-30, 30, -30, 30, step)
    g[:, :2] += rng.uniform(-step / 3, step / 3, (len(g), 2))
    g[:, 2] += rng.normal(0, 0.03, len(g))
    inside = (np.abs(g[:, 0]) < 10) & (np.abs(g[:, 1]) < 6)
    ground = g[~inside]
    roof = g[inside] + [0, 0, 8.0]
    walls = []
    for x0, x1, y0, y1 in ((-10, 10, -6, -6), (-10, 10, 6, 6), (-10, -10, -6, 6), (10, 10, -6, 6)):
        m = int(max(abs(x1 - x0), abs(y1 - y0)) * 8 * density / 5)
        t, z = rng.random(m), rng.uniform(0, 8, m)
        walls.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), z]))
    walls = np.concatenate(walls)
    out = np.column_stack([rng.uniform(-25, 25, 40), rng.uniform(-25, 25, 40), rng.uniform(15, 40, 40)])
    out[::2, 2] = -rng.uniform(3, 6, 20)
    pts = np.concatenate([ground, roof, walls, out])
    ref = np.concatenate([
        np.full(len(ground), L.GROUND), np.full(len(roof) + len(walls), L.BUILDING), np.full(len(out), L.NOISE)
    ]).astype(np.uint8)  # fmt: skip
    return pts, ref


def block_building(n: int = 30_000, seed: int = 0) -> np.ndarray:
    """A 60 m x 60 m ground with a 20 m x 15 m x 8 m block building (roof and four walls)."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(0, 60, n), rng.uniform(0, 60, n), rng.normal(0, 0.02, n)])
    ground = ground[~((ground[:, 0] > 20) & (ground[:, 0] < 40) & (ground[:, 1] > 20) & (ground[:, 1] < 35))]
    m = n // 4
    roof = np.column_stack([rng.uniform(20, 40, m), rng.uniform(20, 35, m), 8 + rng.normal(0, 0.02, m)])
    walls = []
    for x0, x1, y0, y1 in ((20, 40, 20, 20), (20, 40, 35, 35), (20, 20, 20, 35), (40, 40, 20, 35)):
        t, h = rng.uniform(0, 1, m // 2), rng.uniform(0, 8, m // 2)
        walls.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), h]))
    return np.concatenate([ground, roof, *walls])


UTM = np.array([512_345.678, 5_412_345.432, 300.0])
