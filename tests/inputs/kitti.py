"""Small KITTI-layout sequences written to a folder (synthetic sweeps, labels, calibration, poses, times)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

CALIB = "Tr: " + " ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"]) + "\n"


def synthetic_sweep(rings: int = 8, cols: int = 360, seed: int = 0, keep: float = 0.7, with_rings: bool = False):
    """Points ring by ring, azimuth increasing from 0 through +-pi in firing steps of
    ``2 pi / cols`` (a share ``keep`` of the firings return), like a KITTI bin; with
    ``with_rings`` also the ring and the firing (column) of every point."""
    rng = np.random.default_rng(seed)
    pts, ring, col = [], [], []
    for k in range(rings):
        fired = np.flatnonzero(rng.random(cols) < keep)
        az = (fired + 0.5) * 2 * np.pi / cols
        el = np.radians(-20 + 2.5 * k)
        r = rng.uniform(5, 30, len(az))
        x, y, z = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el) * np.ones(len(az))
        pts.append(np.stack([x, y, z, rng.random(len(az))], axis=1))
        ring.append(np.full(len(az), k))
        col.append(fired)
    pts = np.concatenate(pts).astype(np.float32)
    return (pts, np.concatenate(ring), np.concatenate(col)) if with_rings else pts


def make_kitti(root: Path, frames: int = 2, labels: bool = True) -> Path:
    """A KITTI folder of ``frames`` synthetic sweeps with calibration, times 0.1 s apart, poses 1 m apart
    along x and (``labels``) SemanticKITTI labels: road (40) below z = -3 m, building (50) above."""
    (root / "velodyne").mkdir(parents=True)
    for i in range(frames):
        pts = synthetic_sweep(seed=i)
        pts.tofile(root / "velodyne" / f"{i:06d}.bin")
        if labels:
            (root / "labels").mkdir(exist_ok=True)
            sem = np.where(pts[:, 2] < -3, 40, 50).astype(np.uint32) | (np.uint32(7) << 16)
            sem.tofile(root / "labels" / f"{i:06d}.label")
    (root / "calib.txt").write_text(CALIB)
    (root / "times.txt").write_text("".join(f"{0.1 * i:e}\n" for i in range(frames)))
    pose = "1 0 0 {x} 0 1 0 0 0 0 1 0\n"
    (root / "poses.txt").write_text("".join(pose.format(x=i) for i in range(frames)))
    return root


def kitti_folder(root: Path, numbers: list[int], n_lines: int) -> Path:
    """A KITTI layout with sweeps ``NNNNNN.bin`` for ``numbers`` and ``n_lines`` poses (pose k at
    x = k metres) and times (k x 0.1 s), an identity ``Tr``."""
    from tests.inputs.grids import spinning_grid

    (root / "velodyne").mkdir(parents=True)
    for k in numbers:
        g = spinning_grid(seed=k).reshape(-1, 3)
        g = g[np.isfinite(g).all(axis=1)]
        np.column_stack([g, np.zeros(len(g), np.float32)]).astype(np.float32).tofile(root / "velodyne" / f"{k:06d}.bin")
    poses = np.tile(np.eye(4)[:3].ravel(), (n_lines, 1))
    poses[:, 3] = np.arange(n_lines)
    np.savetxt(root / "poses.txt", poses)
    np.savetxt(root / "times.txt", np.arange(n_lines) * 0.1)
    (root / "calib.txt").write_text("Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    return root
