"""Organised sweeps of a spinning sensor in a round room, as ``(beams, cols, 3)`` grids, and folders of
them as PCD sweeps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data_tools.formats.pcd import write_pcd


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


def flat_fields(grid: np.ndarray) -> dict[str, np.ndarray]:
    """The grid's points as flat ``x``, ``y``, ``z`` fields (rows one after the other), as PCD writers take them."""
    g = grid.reshape(-1, 3)
    return {"x": g[:, 0], "y": g[:, 1], "z": g[:, 2]}


def write_room_sweeps(root: Path, n: int, time_field: dict[str, np.ndarray] | None) -> list[int]:
    """``n`` unorganised 16-beam sweeps in firing order (no-returns dropped); returns their sizes."""
    sizes = []
    for i in range(n):
        grid = spinning_grid(seed=i)
        fields = flat_fields(np.swapaxes(grid, 0, 1))  # firing order: all beams of a column together
        ok = np.isfinite(fields["x"])
        fields = {k: v[ok] for k, v in fields.items()}
        if time_field is not None:
            fields.update(
                {k: np.swapaxes(np.broadcast_to(v, grid.shape[:2]), 0, 1).ravel()[ok] for k, v in time_field.items()}
            )
        write_pcd(root / f"{i:06d}.pcd", fields)
        sizes.append(int(ok.sum()))
    return sizes
