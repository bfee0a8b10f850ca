"""Organised sweeps of a spinning sensor in a round room, as ``(beams, cols, 3)`` grids."""

from __future__ import annotations

import numpy as np


def spinning_grid(beams: int = 16, cols: int = 720, fov_deg: float = 30.0, seed: int = 0) -> np.ndarray:
    """One sweep of a spinning sensor as an organised grid ``(beams, cols, 3)`` (rows = rings, top
    beam first) in a round room (walls 12-18 m, floor 1.8 m below); about 5 % no returns (NaN)."""
    rng = np.random.default_rng(seed)
    el = np.radians(np.linspace(fov_deg / 2, -fov_deg / 2, beams))[:, None]
    az = (2 * np.pi * (np.arange(cols) + 0.5) / cols)[None, :]
    r = (15.0 + 3.0 * np.sin(3.0 * az)) / np.cos(el)
    r = np.minimum(r, np.where(el < 0, 1.8 / np.maximum(-np.sin(el), 1e-9), np.inf))
    xyz = np.stack(np.broadcast_arrays(r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)), -1)
    xyz = xyz.astype(np.float32)
    xyz[rng.random((beams, cols)) < 0.05] = np.nan
    return xyz
