"""Ground refinement of a registered pose: height, roll and pitch by point-to-plane against a
local 2.5-D ground model of the map.

KISS-ICP (Vizzo et al., RA-L 2023) registers point to point: a ground point's residual to its
nearest map point is a 3-vector, and only where the map's ground is dense does that nearest point
lie straight below or above it. With the PRC filter's thinned ground (a few hundred registered
ground points a frame against the raw sweep's many hundreds within 20 m) the vertical, the roll
and the pitch, which only the ground fixes in a street, are held loosely (docs/RESULTS.md).

A point-to-plane residual (Chen and Medioni, IVC 1992, "Object modelling by registration of
multiple range images") constrains exactly the component across the surface, so a few well
spread ground points fix those three motions. After KISS-ICP's registration, the frame's ground
points (PRC label ``ground``, the filter's 1 m grid: bounded and well spread) are moved by the
registered pose and matched to the ground plane of their cell in a world-frame horizontal grid;
each cell holds the moments of the registered ground points that fell in it (at most
``max_points`` of them, as KISS-ICP's voxels hold at most ``max_points_per_voxel``), and its
plane ``z = a u + b v + c`` is their least-squares fit. Cells farther than the odometry's range
from the sensor are dropped, as KISS-ICP drops far voxels. Gauss-Newton on
``(t_z, roll, pitch)`` (a rotation about the world's x and y axes through the sensor's position,
linearised as in Low 2004, "Linear least-squares optimization for point-to-plane ICP surface
registration", Tech. Rep. TR04-004, UNC), with the Geman-McClure weight of KISS-ICP (Sec. III-D:
``kernel = sigma / 3``, ``sigma`` its adaptive threshold) and correspondences beyond ``sigma``
left out, refines only those three; the registration's x, y and yaw stay as they were. The
refined pose is the frame's pose: KISS-ICP's map, its adaptive threshold and the ground model go
on from it. The class-aware odometry refines the sweeps it matches class-aware against the same
model.

A cell's plane is kept when its RMS misfit is at most ``max_rms`` (10 cm). The bound must admit
natural ground as well as a road: the misfit of 1 m cells of truth-labelled ground at truth poses
(``scripts/ground_cell_rms.py``) is 3 mm at the median and 11 mm at the 99th percentile on the
simulated street (hdl64, 60 frames), 10 and 87 mm on KITTI 00 (frames 0-2), but 79 mm at the
median on the simulated forest walk (vlp16, uneven terrain, 60 frames): a 5 cm bound kept a third
of its cells and left the walk without a single refined frame; 10 cm keeps 57 % of them.

Measured (docs/RESULTS.md, "Ground refinement"): on urban hdl64 tuning drives (150 frames, seeds
200-202) the prc variant's per-frame vertical error fell from 11-17 mm to 2-6 mm (raw 4-5) and
its roll error from 89-130 to 18-46 mdeg (raw 32-43); on the held-out drives (300 frames, seeds
100-109) prc/raw ATE from 1.27 (median) / 1.59 (worst) to 0.63 / 0.79 at ~0.7 ms a frame
(refinement 0.3, model update 0.4). ``enabled: false`` is KISS-ICP's registration alone (the
paper's pipeline).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field


class GroundConfig(BaseModel):
    """The ground refinement after KISS-ICP's registration (:mod:`prc_slam.odometry.ground`),
    for the variants that give labels (``prc``)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(
        True,
        description="refine height, roll and pitch of every registered frame point-to-plane against the map's "
        "ground (variants with labels only)",
    )
    cell: float = Field(1.0, gt=0, description="horizontal cell (m) of the world-frame ground grid")
    max_points: int = Field(20, ge=3, description="registered ground points a cell's plane is fitted to, at most")
    min_points: int = Field(5, ge=3, description="a cell with fewer points has no plane")
    max_rms: float = Field(
        0.10,
        gt=0,
        description="a cell whose points lie farther than this RMS (m) from their plane is not planar (natural "
        "ground: scripts/ground_cell_rms.py)",
    )
    max_range: float = Field(40.0, gt=0, description="ground points farther from the sensor (m) are not matched")
    iterations: int = Field(5, ge=1, description="Gauss-Newton iterations, at most")
    min_matches: int = Field(30, ge=3, description="fewer matched ground points: the pose is left as registered")


@njit(cache=True, nogil=True, inline="always")
def _slot(ix, iy, mask):
    return ((ix * 73856093) ^ (iy * 19349663)) & mask


@njit(cache=True, nogil=True)
def _find(keys, ix, iy):
    """Slot of cell ``(ix, iy)``, or -1."""
    mask = keys.shape[0] - 1
    h = _slot(ix, iy, mask)
    while keys[h, 2] != 0:
        if keys[h, 0] == ix and keys[h, 1] == iy:
            return h
        h = (h + 1) & mask
    return -1


@njit(cache=True, nogil=True)
def _add(keys, moments, planes, n_cells, points, pose, inv_cell, cell, max_points):
    """Add sensor-frame ground points, moved by ``pose``, to their cells' moments (``n, su, sv, sz, suu, suv, svv,
    suz, svz, szz`` with ``u, v`` the offsets from the cell's corner); a full cell takes no more.
    ``keys[h] = (ix, iy, used)``; the table must have room. Returns the cell count."""
    mask = keys.shape[0] - 1
    for i in range(points.shape[0]):
        p = points[i]
        x = pose[0, 0] * p[0] + pose[0, 1] * p[1] + pose[0, 2] * p[2] + pose[0, 3]
        y = pose[1, 0] * p[0] + pose[1, 1] * p[1] + pose[1, 2] * p[2] + pose[1, 3]
        z = pose[2, 0] * p[0] + pose[2, 1] * p[1] + pose[2, 2] * p[2] + pose[2, 3]
        ix = np.int64(np.floor(x * inv_cell))
        iy = np.int64(np.floor(y * inv_cell))
        h = _slot(ix, iy, mask)
        while keys[h, 2] != 0 and not (keys[h, 0] == ix and keys[h, 1] == iy):
            h = (h + 1) & mask
        if keys[h, 2] == 0:
            keys[h, 0], keys[h, 1], keys[h, 2] = ix, iy, 1
            moments[h, :] = 0.0
            n_cells += 1
        m = moments[h]
        if m[0] >= max_points:
            continue
        u, v = x - ix * cell, y - iy * cell
        m[0] += 1.0
        m[1] += u
        m[2] += v
        m[3] += z
        m[4] += u * u
        m[5] += u * v
        m[6] += v * v
        m[7] += u * z
        m[8] += v * z
        m[9] += z * z
        planes[h, 3] = -1.0  # to be fitted again
    return n_cells


@njit(cache=True, nogil=True)
def _fit(m, out, min_points, max_rms, min_spread2):
    """Least-squares plane ``z = a u + b v + c`` of one cell's moments into ``out = (a, b, c,
    ok)``; ``ok = 0`` with too few points, points along a line (``u, v`` spread below
    ``sqrt(min_spread2)`` across their main direction) or an RMS misfit above ``max_rms``."""
    n = m[0]
    out[3] = 0.0
    if n < min_points:
        return
    mu, mv, mz = m[1] / n, m[2] / n, m[3] / n
    cuu, cuv, cvv = m[4] / n - mu * mu, m[5] / n - mu * mv, m[6] / n - mv * mv
    cuz, cvz, czz = m[7] / n - mu * mz, m[8] / n - mv * mz, m[9] / n - mz * mz
    det = cuu * cvv - cuv * cuv
    tr = cuu + cvv
    lmin = 0.5 * (tr - np.sqrt(max(tr * tr - 4.0 * det, 0.0)))
    if lmin < min_spread2 or det <= 0.0:
        return
    a = (cuz * cvv - cvz * cuv) / det
    b = (cvz * cuu - cuz * cuv) / det
    # residual variance of z about the plane: czz - [a b] C [a b]^T
    var = czz - (a * cuz + b * cvz)
    if var > max_rms * max_rms:
        return
    out[0], out[1], out[2] = a, b, mz - a * mu - b * mv
    out[3] = 1.0


@njit(cache=True, nogil=True)
def _refine(points, pose, keys, moments, planes, inv_cell, cell, min_points, max_rms, min_spread2, kernel, gate,
            iterations, min_matches):  # fmt: skip
    """Gauss-Newton on ``(t_z, roll, pitch)`` of ``pose`` (module docstring). Returns the refined
    pose, the matched points of the last iteration and whether the pose was refined."""
    R = pose[:3, :3].copy()
    t = pose[:3, 3].copy()  # the rotation is about the sensor's position: x and y stay
    matched = 0
    refined = False
    for _ in range(iterations):
        H = np.zeros((3, 3))
        g = np.zeros(3)
        matched = 0
        for i in range(points.shape[0]):
            p = points[i]
            q0 = R[0, 0] * p[0] + R[0, 1] * p[1] + R[0, 2] * p[2] + t[0]
            q1 = R[1, 0] * p[0] + R[1, 1] * p[1] + R[1, 2] * p[2] + t[1]
            q2 = R[2, 0] * p[0] + R[2, 1] * p[1] + R[2, 2] * p[2] + t[2]
            ix = np.int64(np.floor(q0 * inv_cell))
            iy = np.int64(np.floor(q1 * inv_cell))
            h = _find(keys, ix, iy)
            if h < 0:
                continue
            if planes[h, 3] < 0.0:
                _fit(moments[h], planes[h], min_points, max_rms, min_spread2)
            if planes[h, 3] == 0.0:
                continue
            a, b, c = planes[h, 0], planes[h, 1], planes[h, 2]
            s = 1.0 / np.sqrt(1.0 + a * a + b * b)
            nx, ny, nz = -a * s, -b * s, s
            r = (q2 - (a * (q0 - ix * cell) + b * (q1 - iy * cell) + c)) * s
            if abs(r) > gate:
                continue
            w = 1.0 / (1.0 + (r / kernel) ** 2) ** 2  # Geman-McClure
            dx, dy, dz = q0 - t[0], q1 - t[1], q2 - t[2]
            # d r / d(t_z, w_x, w_y) = (n_z, (d x n)_x, (d x n)_y)
            j0, j1, j2 = nz, dy * nz - dz * ny, dz * nx - dx * nz
            H[0, 0] += w * j0 * j0
            H[0, 1] += w * j0 * j1
            H[0, 2] += w * j0 * j2
            H[1, 1] += w * j1 * j1
            H[1, 2] += w * j1 * j2
            H[2, 2] += w * j2 * j2
            g[0] += w * j0 * r
            g[1] += w * j1 * r
            g[2] += w * j2 * r
            matched += 1
        if matched < min_matches:
            break
        H[1, 0], H[2, 0], H[2, 1] = H[0, 1], H[0, 2], H[1, 2]
        if np.linalg.det(H) <= 1e-12 * (H[0, 0] * H[1, 1] * H[2, 2] + 1e-300):
            break
        d = -np.linalg.solve(H, g)
        wx, wy = d[1], d[2]
        th = np.sqrt(wx * wx + wy * wy)
        K = np.zeros((3, 3))
        K[0, 2], K[1, 2], K[2, 0], K[2, 1] = wy, -wx, -wy, wx
        dR = np.eye(3)
        if th > 1e-15:
            dR += (np.sin(th) / th) * K + ((1.0 - np.cos(th)) / (th * th)) * (K @ K)
        R = dR @ R
        t[2] += d[0]
        refined = True
        if abs(d[0]) < 1e-5 and th < 1e-6:
            break
    out = pose.copy()
    out[:3, :3] = R
    out[:3, 3] = t
    return out, matched, refined


@njit(cache=True, nogil=True)
def _rehash(keys, moments, planes, size, origin, max_d2, cell):
    """A table of ``size`` slots with the cells within ``sqrt(max_d2)`` of ``origin`` (x-y)."""
    nk = np.zeros((size, 3), np.int64)
    nm = np.zeros((size, 10))
    npl = np.zeros((size, 4))
    mask = size - 1
    n = 0
    for h in range(keys.shape[0]):
        if keys[h, 2] == 0:
            continue
        ix, iy = keys[h, 0], keys[h, 1]
        dx, dy = (ix + 0.5) * cell - origin[0], (iy + 0.5) * cell - origin[1]
        if dx * dx + dy * dy > max_d2:
            continue
        s = _slot(ix, iy, mask)
        while nk[s, 2] != 0:
            s = (s + 1) & mask
        nk[s] = keys[h]
        nm[s] = moments[h]
        npl[s] = planes[h]
        n += 1
    return nk, nm, npl, n


class GroundModel:
    """The map's ground as planes on a world-frame horizontal grid (module docstring).

    Parameters
    ----------
    config : GroundConfig
    max_range : float
        Cells farther than this (m, x-y) from the sensor are dropped (the odometry's range).
    """

    def __init__(self, config: GroundConfig, max_range: float) -> None:
        self.config = config
        self.max_range = float(max_range)
        self.inv_cell = 1.0 / config.cell
        self.n = 0
        self._alloc(1 << 12)

    def _alloc(self, size: int) -> None:
        self.keys = np.zeros((size, 3), np.int64)
        self.moments = np.zeros((size, 10))
        self.planes = np.zeros((size, 4))

    def update(self, points: np.ndarray, pose: np.ndarray) -> None:
        """Add a registered frame's ground points (sensor frame, ``float (N, 3)``) at ``pose``, then
        drop the cells beyond ``max_range`` of the sensor."""
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"ground points must be (N, 3), got {pts.shape}")
        pose = np.ascontiguousarray(pose, dtype=np.float64)
        size = self.keys.shape[0]
        if 2 * (self.n + len(pts)) > size:  # drop far cells, and grow until half the slots are free
            need = max(size, 1 << int(np.ceil(np.log2(2 * (self.n + len(pts)) + 1))))
            self.keys, self.moments, self.planes, self.n = _rehash(
                self.keys, self.moments, self.planes, need, pose[:2, 3].copy(), self.max_range**2, self.config.cell
            )
        self.n = _add(self.keys, self.moments, self.planes, self.n, pts, pose, self.inv_cell, self.config.cell,
                      self.config.max_points)  # fmt: skip

    def refine(self, points: np.ndarray, pose: np.ndarray, sigma: float) -> tuple[np.ndarray, int, bool]:
        """Refine ``pose``'s height, roll and pitch (module docstring).

        Parameters
        ----------
        points : float (N, 3)
            The frame's ground points in the sensor frame.
        pose : float (4, 4)
            The registered pose (sensor to world).
        sigma : float
            KISS-ICP's adaptive threshold: kernel ``sigma / 3``, matches within ``sigma``.

        Returns
        -------
        pose : float (4, 4)
            Refined, or ``pose`` itself when fewer than ``min_matches`` points matched a plane.
        matched : int
            Ground points matched to a plane at the last iteration.
        refined : bool
        """
        cfg = self.config
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"ground points must be (N, 3), got {pts.shape}")
        if not self.n or not len(pts):
            return np.array(pose, dtype=np.float64), 0, False
        min_spread2 = (0.15 * cfg.cell) ** 2
        return _refine(pts, np.ascontiguousarray(pose, dtype=np.float64), self.keys, self.moments, self.planes,
                       self.inv_cell, cfg.cell, cfg.min_points, cfg.max_rms, min_spread2, sigma / 3.0, float(sigma),
                       cfg.iterations, cfg.min_matches)  # fmt: skip


def ground_points(points: np.ndarray, labels: np.ndarray, codes: list[int], min_range: float, max_range: float):
    """The points labelled with one of ``codes`` whose distance from the sensor lies within
    ``(min_range, max_range]``."""
    mask = labels == codes[0] if len(codes) == 1 else np.isin(labels, np.asarray(codes, dtype=labels.dtype))
    chosen = points[mask]  # the ranges of the labelled points only: a sweep's ground is a fraction of it
    r2 = np.einsum("ij,ij->i", chosen, chosen)
    return chosen[(r2 > min_range * min_range) & (r2 <= max_range * max_range)]
