"""Classification after registration (paper 004): the whole in-memory pipeline.

Order as in the paper's Sec. 4: outliers by local density (Sec. 3.1, 4), normals and
segmentation (Sec. 3.2, 5), ground (4.1), buildings (4.2), vehicles (4.3), posts (4.4),
vegetation (4.5); each step sees only what the earlier ones left. Codes as in DESIGN.md:
outliers are ``noise``, points left at the end ``unclassified``, non-finite input points
``no_return`` (counted in :attr:`MapResult.nonfinite`).

At any point density: with ``density_relative`` (default) the Sec. 3.1 threshold and
the voxel and cell sizes follow the cloud's own surface density
(:mod:`prc_slam.mapclass.density`), so airborne tiles of 2-20 points/m^2 and terrestrial scans
classify as mobile-mapping maps do; the paper's fixed values stay under :func:`paper_config`.
A :class:`DensityWarning` says when more than ``density_warn_share`` of the cloud falls under
the threshold. ``mode="forest"`` reports slim pillars as ``trunk`` and foliage as vegetation.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from prc_slam import labels as L
from prc_slam.mapclass import metrics as M
from prc_slam.mapclass.density import DensityScale, below_message, outlier_threshold, size_for, surface_density
from prc_slam.mapclass.ground import detect_ground
from prc_slam.mapclass.objects import (
    detect_buildings,
    detect_posts,
    detect_vegetation,
    detect_vehicles,
    ground_height_grid,
    height_above_ground,
    scene_voxel_count,
    segment_voxels,
    under_crown,
)
from prc_slam.mapclass.order import is_local, spatial_order
from prc_slam.util.threads import side_by_side
from prc_slam.util.voxels import VoxelGrid

#: the Sec. 4.2 building voxel (m; :func:`detect_buildings`' default)
BUILDING_VOXEL = 0.33


class _Params(BaseModel):
    model_config = ConfigDict(extra="forbid")


class GroundParams(_Params):
    cell: float = Field(0.5, gt=0, description="terrain grid cell (m)")
    local_radius: float = Field(3.0, gt=0, description="window half-width of the local minimum (m)")
    max_slope: float = Field(0.3, ge=0, description="largest rise per metre along a scan line")
    max_step: float = Field(0.1, ge=0, description="rise allowed on top of the slope (m)")
    max_above_local: float = Field(0.5, ge=0, description="largest height above the local minimum (m)")
    tolerance: float = Field(0.2, ge=0, description="points up to this far above a ground cell's minimum (m)")
    points_per_cell: float = Field(
        4.0, gt=0, description="relative density: the cell grows until a surface of the cloud's density fills it so"
    )
    terrain: Literal["auto", "on", "off"] = Field(
        "auto",
        description="terrain-relative tests (slopes, terraces, hills; ground.detect_ground); off = paper. auto: on "
        "for clouds of airborne density (under terrain_max_density) and where the terrain is not level",
    )
    terrain_max_density: float = Field(100.0, ge=0, description="auto: surface points/m^2 of an airborne cloud")
    min_relief: float = Field(0.05, ge=0, description="auto: median slope of the terrain (rise/m) not level")
    min_support: int = Field(
        5,
        ge=1,
        description="a cell's terrain height is its lowest point with this many points (itself included) within "
        "tolerance; at most a quarter of the points the cloud's surface density puts in a cell; 1 = paper",
    )


class BuildingParams(_Params):
    min_segment_points: int | None = Field(None, ge=1, description="'large' segment by points (paper)")
    min_segment_voxels: int = Field(50, ge=1, description="'large' by 0.33 m voxels occupied (when points unset)")
    min_verticality: float = Field(0.6, ge=0, le=1)
    min_height: float = Field(2.0, ge=0, description="first pass: segments this tall (m) ...")
    min_reach: float = Field(6.0, ge=0, description="... or this long (m, longer than a car); both 0 = paper")
    near: float = Field(3.0, ge=0, description="large segments' points this close join (m)")
    close: float = Field(1.5, ge=0, description="segments with two thirds of their points this close join (m)")
    spare_objects: bool = Field(True, description="the 1.5 m pass skips segments of foliage or posts; False = paper")
    roof_height: float = Field(
        2.5, ge=0, description="also seed with large level non-foliage segments this high above ground (m); 0 = paper"
    )
    under_roof: float = Field(
        0.5, ge=0, description="points within a cell of this side (m; >= point spacing) under roofs join; 0 = paper"
    )


class VehicleParams(_Params):
    min_points: int = Field(30, ge=1)
    min_length: float = Field(1.0, ge=0)
    max_length: float = Field(6.0, gt=0)
    max_width: float = Field(2.5, gt=0)
    min_height: float = Field(0.4, ge=0)
    max_height: float = Field(3.5, gt=0)
    max_ground_gap: float = Field(0.6, ge=0, description="segment bottom above the nearby ground (m)")
    max_verticality: float = Field(0.6, ge=0, le=1, description="mean verticality of a car (1 = paper)")
    skip_foliage: bool = Field(True, description="segments or groups mostly of foliage are no cars; False = paper")
    group_voxel: float = Field(0.3, ge=0, description="also test touching segments as one (voxel, m); 0 = paper")


class PostParams(_Params):
    voxel: float = Field(0.25, gt=0)
    min_voxel_points: int = Field(3, ge=1, description="a voxel with fewer points is empty")
    max_extent: float = Field(1.0, gt=0, description="horizontal reach of filled voxels (m)")
    min_height: float = Field(1.5, gt=0)
    skip_stems: bool = Field(True, description="pillars under foliage are stems, left to vegetation; False = paper")


class VegetationParams(_Params):
    voxel: float = Field(1.0, gt=0)
    factor: float = Field(2.0, gt=0, description="segment density above factor x average")
    min_similar: int = Field(2, ge=0, description="neighbouring voxels that high")
    foliage_only: bool = Field(True, description="also ask for foliage (MapClassConfig.foliage_share); False = paper")
    canopy_share: float | None = Field(
        0.5,
        ge=0,
        le=1,
        description="urban: where foliage is this share of the points off the ground or more (a wooded tile), "
        "Sec. 4.5's 'higher than on average' has no contrast and foliage alone is vegetation, as in forest mode; "
        "None = paper",
    )


class MapClassConfig(_Params):
    """Paper 004's parameters (Sec. 3, 4) and the formulation choices; see README for figures."""

    mode: Literal["urban", "forest"] = Field(
        "urban", description="forest: slim pillars are stems (trunk), none are lamp posts or signs"
    )
    density_voxel: float = Field(0.33, gt=0, description="Sec. 3.1 voxel side (m); the least with density_relative")
    min_density: float = Field(100.0, ge=0, description="paper: points/m^3 below which a point is an outlier")
    density_relative: bool = Field(
        True, description="sizes and the outlier threshold from the cloud's own density (False = paper's fixed values)"
    )
    density_points: float = Field(50.0, gt=0, description="relative: surface points in the 3x3x3 density voxels")
    normal_points: float = Field(27.0, gt=0, description="relative: surface points in the 3x3x3 normal voxels")
    density_percentile: float = Field(5.0, gt=0, lt=100, description="relative: threshold from this percentile ...")
    density_fraction: float = Field(0.25, gt=0, le=1, description="... times this share of it")
    density_min_points: float = Field(2.0, ge=0, description="relative: at least this many points in 3x3x3 voxels")
    density_warn_share: float = Field(0.1, ge=0, le=1, description="message when more of the cloud is under it")
    normals: Literal["voxels", "points"] = "voxels"
    normal_voxel: float = Field(0.2, gt=0, description="voxel side of the 'voxels' normals (m)")
    knn: int = Field(16, ge=3, description="neighbours of the 'points' normals")
    knn_radius: float = Field(1.0, gt=0, description="search radius of the 'points' normals (m)")
    theta_deg: float = Field(8.0, gt=0, le=90, description="region growing: normal angle to the seed")
    max_curvature: float = Field(0.05, gt=0, description="region growing: largest curvature of a seed")
    foliage_share: float = Field(
        0.4, ge=0, le=1, description="foliage: this share of the nearby points in segments of <= 2 normal voxels"
    )
    foliage_voxel: float = Field(0.5, gt=0, description="foliage: 'nearby' = the 3x3x3 voxels of this side (m)")
    small_segment_points: int = Field(200, ge=1, description="'small' adjacent segments (Sec. 4.3, 4.4)")
    spatial_order: Literal["auto", "always", "never"] = Field(
        "auto",
        description="points sorted along a Z-order curve first (speed; 'always': labels independent of the input "
        "order); 'auto': unless the input order is already local (mapclass.order.is_local)",
    )
    order_step: float = Field(
        10.0, gt=0, description="'auto': local when 90 % of the steps between consecutive points are this short (m)"
    )
    ground: GroundParams = Field(default_factory=GroundParams)
    building: BuildingParams = Field(default_factory=BuildingParams)
    vehicle: VehicleParams = Field(default_factory=VehicleParams)
    post: PostParams = Field(default_factory=PostParams)
    vegetation: VegetationParams = Field(default_factory=VegetationParams)


def paper_config() -> MapClassConfig:
    """Paper 004's steps only: every addition of ours turned off (the voxel formulation of the
    normals and 'large' measured in occupied voxels stay; ``normals="points"`` selects the
    per-point formulation)."""
    return MapClassConfig(
        density_relative=False,
        ground=GroundParams(terrain="off", min_support=1),
        building=BuildingParams(min_height=0.0, min_reach=0.0, spare_objects=False, roof_height=0.0, under_roof=0.0),
        vehicle=VehicleParams(max_verticality=1.0, group_voxel=0.0, skip_foliage=False),
        vegetation=VegetationParams(foliage_only=False, canopy_share=None),
        post=PostParams(skip_stems=False),
    )


@dataclass
class MapResult:
    """Labels and metrics per input point, stage times (s), the count of non-finite points, the
    sizes and threshold used (``scale``), the share of points under the density threshold, the
    messages about the input (also issued as :class:`DensityWarning`) and what the cloud decided
    (``choices``: ``terrain``, whether the ground took the terrain-relative tests, ``relief``, the
    terrain's median slope, when measured, ``raised_cells``, the ground cells whose lowest point
    lacked company and was passed over (``GroundParams.min_support``), and ``canopy``, the share
    of foliage off the ground, when a wooded tile took foliage alone as vegetation)."""

    labels: np.ndarray
    segment: np.ndarray
    density: np.ndarray
    verticality: np.ndarray
    seconds: dict[str, float] = field(default_factory=dict)
    nonfinite: int = 0
    scale: DensityScale | None = None
    below_share: float = 0.0
    messages: list[str] = field(default_factory=list)
    choices: dict = field(default_factory=dict)


class DensityWarning(UserWarning):
    """More of the cloud than ``density_warn_share`` falls under the Sec. 3.1 threshold."""


class _Clock:
    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] = self.seconds.get(name, 0.0) + now - self.t
        self.t = now

    def record(self, seconds: dict[str, float]) -> None:
        """Stages that ran side by side: each its own seconds (together more than the time
        since the last lap); the clock restarts."""
        for name, sec in seconds.items():
            self.seconds[name] = self.seconds.get(name, 0.0) + sec
        self.t = time.perf_counter()


def classify_map(points: np.ndarray, config: MapClassConfig | None = None) -> MapResult:
    """Classify a registered cloud (world frame, z up).

    Parameters
    ----------
    points : float (N, 3)
    config : MapClassConfig, optional

    Returns
    -------
    MapResult
        One label per input point, in input order; the input is not modified.
    """
    cfg = config or MapClassConfig()
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {pts.shape}")
    clock = _Clock()
    finite = _finite_rows(pts)
    n_bad = int(len(pts) - finite.sum())
    if n_bad:
        pts = np.compress(finite, pts, axis=0)
    order = None
    if len(pts) > 1 and (
        cfg.spatial_order == "always" or (cfg.spatial_order == "auto" and not is_local(pts, cfg.order_step))
    ):
        order = spatial_order(pts)
        pts = _take_rows(pts, order)
        clock.lap("order")
    scale = density_scale(pts, cfg)
    choices: dict = {}
    lab, seg, density, vert = _classify_finite(pts, cfg, clock, scale, choices)
    if order is not None:
        lab, seg, density, vert = _unpermute(order, lab, seg, density, vert)
    below = float(np.mean(density < scale.threshold)) if len(density) else 0.0
    messages = []
    if below > cfg.density_warn_share:
        median = float(np.median(density))
        messages.append(below_message(below, scale.threshold, median, scale.relative, cfg.min_density))
        warnings.warn(messages[-1], DensityWarning, stacklevel=2)
    if not n_bad:
        return MapResult(lab, seg, density, vert, clock.seconds, 0, scale, below, messages, choices)
    out = MapResult(
        np.full(len(finite), L.NO_RETURN, np.uint8), np.full(len(finite), -1, np.int64),
        np.zeros(len(finite)), np.zeros(len(finite)), clock.seconds, n_bad, scale, below, messages, choices,
    )  # fmt: skip
    out.labels[finite], out.segment[finite], out.density[finite], out.verticality[finite] = lab, seg, density, vert
    return out


# Large outputs are allocated by numpy and filled by the kernels: numpy asks the kernel for huge
# pages on large arrays (madvise), numba's own allocations get 4 kB pages, whose first touch
# costs ~0.8 ms per MB here against ~0.2 ms (0.1 s for a 5 M-point (N, 3) array).


def _inliers(density, threshold, points, labels, noise):
    """Sec. 3.1 split: ``labels`` set to ``noise`` where ``density < threshold``; the other
    points' indices and rows."""
    m = _mark_outliers(density, threshold, labels, noise)
    idx, p = np.empty(m, np.int64), np.empty((m, 3))
    _fill_inliers(density, threshold, points, idx, p)
    return idx, p


@njit(cache=True, nogil=True)
def _mark_outliers(density, threshold, labels, noise):
    m = 0
    for i in range(density.shape[0]):
        if density[i] >= threshold:
            m += 1
        else:
            labels[i] = noise
    return m


@njit(cache=True, nogil=True)
def _fill_inliers(density, threshold, points, idx, p):
    m = 0
    for i in range(density.shape[0]):
        if density[i] >= threshold:
            idx[m] = i
            p[m, 0], p[m, 1], p[m, 2] = points[i, 0], points[i, 1], points[i, 2]
            m += 1


def _unpermute(order, *arrays):
    """Arrays of the points ``order`` (a permutation) back in the points' order: ``out[order] = a``."""
    outs = tuple(np.empty_like(a) for a in arrays)
    _scatter4(order, *arrays, *outs)
    return outs


@njit(cache=True, nogil=True)
def _scatter4(order, a, b, c, d, oa, ob, oc, od):
    for k in range(order.shape[0]):
        i = order[k]
        oa[i], ob[i], oc[i], od[i] = a[k], b[k], c[k], d[k]


def _voxel_segment_per_point(seg_v, voxel):
    """Each point's segment (its voxel's) and whether that segment spans at most two voxels."""
    seg, tiny = np.empty(len(voxel), np.int64), np.empty(len(voxel), bool)
    _fill_voxel_segments(seg_v, voxel, seg, tiny)
    return seg, tiny


@njit(cache=True, nogil=True)
def _fill_voxel_segments(seg_v, voxel, seg, tiny):
    n_seg = seg_v.max() + 1 if seg_v.shape[0] else 0
    size = np.zeros(n_seg, np.int64)
    for v in range(seg_v.shape[0]):
        size[seg_v[v]] += 1
    for i in range(voxel.shape[0]):
        s = seg_v[voxel[i]]
        seg[i] = s
        tiny[i] = size[s] <= 2


def _take_rows(a, idx):
    """``a[idx]`` of an (N, 3) array (``np.take`` of rows costs ~50 ns a row)."""
    out = np.empty((len(idx), 3), a.dtype)
    _fill_rows(a, idx, out)
    return out


@njit(cache=True, nogil=True)
def _fill_rows(a, idx, out):
    for k in range(idx.shape[0]):
        i = idx[k]
        out[k, 0], out[k, 1], out[k, 2] = a[i, 0], a[i, 1], a[i, 2]


@njit(cache=True, nogil=True)
def _scatter(out, idx, values):
    """``out[idx] = values``."""
    for k in range(idx.shape[0]):
        out[idx[k]] = values[k]


def _split_points(ground, labels, code, idx, p, v):
    """``labels[idx[ground]] = code``; the ground rows of ``p``, and ``idx, p, v`` of the other
    points, in one pass (the part of the ground split that needs nothing of the segmentation)."""
    ng = int(np.count_nonzero(ground))
    m = len(ground) - ng
    out = np.empty((ng, 3)), np.empty(m, np.int64), np.empty((m, 3)), np.empty(m)
    _fill_split_points(ground, labels, code, idx, p, v, *out)
    return out


@njit(cache=True, nogil=True)
def _fill_split_points(ground, labels, code, idx, p, v, gp, idx2, p2, v2):
    a = b = 0
    for i in range(ground.shape[0]):
        if ground[i]:
            labels[idx[i]] = code
            gp[a, 0], gp[a, 1], gp[a, 2] = p[i, 0], p[i, 1], p[i, 2]
            a += 1
        else:
            idx2[b], v2[b] = idx[i], v[i]
            p2[b, 0], p2[b, 1], p2[b, 2] = p[i, 0], p[i, 1], p[i, 2]
            b += 1


def _split_segments(ground, m, seg, tiny):
    """``seg, tiny`` of the ``m`` points off the ground."""
    out = np.empty(m, np.int64), np.empty(m, bool)
    _fill_split_segments(ground, seg, tiny, *out)
    return out


@njit(cache=True, nogil=True)
def _fill_split_segments(ground, seg, tiny, seg2, tiny2):
    b = 0
    for i in range(ground.shape[0]):
        if not ground[i]:
            seg2[b], tiny2[b] = seg[i], tiny[i]
            b += 1


@njit(cache=True, nogil=True)
def _finite_rows(points):
    """``np.isfinite(points).all(axis=1)`` in one pass."""
    out = np.empty(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        out[i] = np.isfinite(points[i, 0]) and np.isfinite(points[i, 1]) and np.isfinite(points[i, 2])
    return out


def density_scale(points: np.ndarray, cfg: MapClassConfig) -> DensityScale:
    """The voxel sizes of this cloud (see :mod:`prc_slam.mapclass.density`); the threshold is
    filled in by the density step."""
    if not cfg.density_relative:
        return DensityScale(0.0, cfg.density_voxel, cfg.normal_voxel, cfg.ground.cell, cfg.min_density, False)
    rho = surface_density(points)
    return DensityScale(
        rho,
        size_for(rho, cfg.density_points, cfg.density_voxel),
        size_for(rho, cfg.normal_points, cfg.normal_voxel),
        max(cfg.ground.cell, float(np.sqrt(cfg.ground.points_per_cell / rho)) if rho > 0 else cfg.ground.cell),
    )


def _classify_finite(
    pts: np.ndarray, cfg: MapClassConfig, clock: _Clock, scale: DensityScale, choices: dict
) -> tuple[np.ndarray, ...]:
    n = len(pts)
    labels = np.full(n, L.UNCLASSIFIED, dtype=np.uint8)
    segment = np.full(n, -1, dtype=np.int64)
    vert = np.zeros(n)
    # Sec. 3.1 / 4: outliers by local density (threshold relative to the cloud unless paper)
    # the normals' grid of every point is built beside the density grid (it needs no density);
    # the inliers' grid is then that grid's subset
    voxels = cfg.normals == "voxels"
    ((density, dgrid), all_grid), _ = side_by_side(
        lambda: M.local_density(pts, scale.density_voxel),
        lambda: VoxelGrid.build(pts, scale.normal_voxel) if voxels else None,
    )
    if scale.relative:
        scale.threshold = outlier_threshold(
            density, scale.density_voxel, cfg.density_percentile, cfg.density_fraction, cfg.density_min_points
        )
    idx, p = _inliers(density, scale.threshold, pts, labels, L.NOISE)
    clock.lap("density")
    if len(idx) == 0:
        return labels, segment, density, vert
    # Sec. 3.2 / 5: normals and segmentation (and each segment's size in normal voxels)
    if voxels:
        sub = all_grid if len(idx) == n else all_grid.subset(idx)
        grid, normals, curv_v = M.voxel_normals(p, scale.normal_voxel, sub)
        normal_of = grid.voxel  # every point takes its voxel's normal
    else:
        normals, curv, nb = M.knn_normals(p, cfg.knn, cfg.knn_radius)
        normal_of = None
    clock.lap("normals")

    def segmentation() -> tuple[np.ndarray, np.ndarray]:
        if cfg.normals == "voxels":
            seg_v = M.voxel_segments(grid, normals, curv_v, cfg.theta_deg, cfg.max_curvature)
            seg, tiny = _voxel_segment_per_point(seg_v, grid.voxel)
        else:
            seg, ns = M.region_growing(normals, curv, nb, np.cos(np.radians(cfg.theta_deg)), cfg.max_curvature)
            tiny = segment_voxels(p, seg, ns, scale.normal_voxel)[seg] <= 2
        _scatter(segment, idx, seg)
        return seg, tiny

    def ground_mask() -> tuple[np.ndarray, tuple[np.ndarray, ...], float]:
        """Sec. 4.1 ground (needs nothing of the segmentation), then the Sec. 3.4 verticality
        on the density voxels (inliers only; needs the normals alone; its seconds) and the split
        of the points, off the ground or not."""
        g = cfg.ground
        airborne = 0 < scale.rho < g.terrain_max_density
        terrain = {"on": True, "off": False}.get(g.terrain, True if airborne else "auto")
        # a surface of the cloud's density leaves rho * cell^2 points in a cell
        support = min(g.min_support, max(1, int(scale.rho * scale.ground_cell**2 / 4)))
        mask = detect_ground(
            p, scale.ground_cell, g.local_radius, g.max_slope, g.max_step, g.max_above_local, g.tolerance,
            terrain_relative=terrain, min_relief=g.min_relief, min_support=support, reach=3 * scale.density_voxel,
            info=choices,
        )  # fmt: skip
        t = time.perf_counter()
        v = M.verticality(normals, dgrid.voxel, dgrid.n_voxels, normal_of, idx)
        _scatter(vert, idx, v)
        t_vert = time.perf_counter() - t
        # the ground split of the points (and their verticality) while the segmentation runs
        return mask, _split_points(mask, labels, L.GROUND, idx, p, v), t_vert

    ((seg, tiny), (ground, split, t_vert)), (t_seg, t_ground) = side_by_side(segmentation, ground_mask)
    t_ground -= t_vert
    clock.record({"segmentation": t_seg, "verticality": t_vert})
    t = time.perf_counter()
    ground_pts, idx, p, v = split
    seg, tiny = _split_segments(ground, len(idx), seg, tiny)
    scene = p
    clock.record({"ground": t_ground + time.perf_counter() - t})
    # foliage: where most points lie in segments of at most two normal voxels (see
    # MapClassConfig.foliage_share); posts: the Sec. 4.4 test on everything left (side by side)
    e, q = cfg.vegetation, cfg.post
    coarse = scale.normal_voxel / cfg.normal_voxel  # > 1 on clouds sparser than the paper's
    # in urban mode Sec. 4.2 comes first, on these same points: its grid is built meanwhile
    # ... and the roof seeds' heights above ground (the only step here with parallel kernels: in
    # the calling thread)
    b, c = cfg.building, cfg.vehicle
    (hag, foliage, post, building_grid), (t_hag, t_foliage, t_posts, t_grid) = side_by_side(
        lambda: height_above_ground(p, ground_pts, cell=max(2.5, 2 * scale.ground_cell), radius=3)
        if b.roof_height > 0 else None,
        lambda: M.fragmentation(p, tiny, cfg.foliage_voxel * coarse) >= cfg.foliage_share,
        lambda: detect_posts(p, seg, q.voxel, q.min_voxel_points, q.max_extent, q.min_height, cfg.small_segment_points),
        lambda: VoxelGrid.build(p, BUILDING_VOXEL) if cfg.mode == "urban" else None,
    )  # fmt: skip
    clock.record({"foliage_posts": t_foliage + t_posts, "buildings": t_grid + t_hag})
    # Sec. 4.2-4.5, each on what the previous steps left
    pt = {"p": p, "seg": seg, "vert": v, "foliage": foliage, "post": post}
    if b.roof_height > 0:  # roof seeds: high above the ground and not foliage
        pt["roof"] = (hag >= b.roof_height) & ~foliage & ~post

    def posts_not_stems(t: dict[str, np.ndarray]) -> np.ndarray:
        """Sec. 4.4 posts; with ``skip_stems`` those under foliage are stems (next step)."""
        pillar = detect_posts(
            t["p"], t["seg"], q.voxel, q.min_voxel_points, q.max_extent, q.min_height, cfg.small_segment_points
        )
        t["stem"] = pillar & under_crown(t["p"], t["foliage"]) if q.skip_stems else np.zeros(len(pillar), bool)
        return pillar & ~t["stem"]

    def buildings(t: dict[str, np.ndarray]) -> np.ndarray:
        """Sec. 4.2, with the roof seeds and the points under them (walls an airborne scanner
        sees at a glance, in pieces too small for normals) when configured."""
        roof = np.zeros(len(t["p"]), bool)
        hit = detect_buildings(
            t["p"], t["seg"], t["vert"], b.min_segment_points, b.min_verticality, b.min_height, b.near, b.close,
            spare=t["foliage"] | t["post"] if b.spare_objects else None,
            min_segment_voxels=b.min_segment_voxels, min_reach=b.min_reach, roof=t.get("roof"),
            seeds_out=roof, grid=building_grid if t["p"] is p else None)  # fmt: skip
        if b.under_roof > 0 and roof.any():
            cell = max(b.under_roof, 1.0 / np.sqrt(scale.rho)) if scale.rho > 0 else b.under_roof
            hit |= under_crown(t["p"], roof, cell=cell, reach=1, above=0.5) & ~t["post"]
        return hit

    # made beside the buildings step (serial kernels; the other core is free): what later steps
    # need of the ground and the scene alone
    ahead: dict = {}

    def prepare() -> None:
        if len(ground_pts):
            ahead["ground_heights"] = ground_height_grid(ground_pts, 1.0, 3)  # detect_vehicles' own
        if cfg.mode == "urban":
            ahead["scene_voxels"] = scene_voxel_count(scene, e.voxel)

    steps = [
        ("buildings", L.BUILDING, buildings),
        ("vehicles", L.VEHICLE, lambda t: detect_vehicles(
            t["p"], t["seg"], ground_pts, c.min_points, (c.min_length, c.max_length), c.max_width,
            (c.min_height, c.max_height), c.max_ground_gap, cfg.small_segment_points, c.group_voxel,
            t["foliage"] if c.skip_foliage else None, t["vert"], c.max_verticality,
            t["post"] if c.group_voxel > 0 else None, ahead.get("ground_heights"))),
        ("posts", L.POLE, posts_not_stems),
        ("stems", L.VEGETATION, lambda t: t["stem"]),
        ("vegetation", L.VEGETATION, lambda t: detect_vegetation(
            t["p"], t["seg"], scene, e.voxel, e.factor, e.min_similar, ahead.get("scene_voxels"))
            & (t["foliage"] if e.foliage_only else True)),
    ]  # fmt: skip
    if cfg.mode == "forest":
        # every slim pillar is a stem, taken before the facade test sees it; the canopy is
        # everywhere, so Sec. 4.5's "distinctively higher than on average" has no contrast:
        # foliage alone is vegetation
        steps = [("stems", L.TRUNK, lambda t: t["post"])] + [s for s in steps if s[0] not in ("posts", "stems")]
        steps[-1] = ("vegetation", L.VEGETATION, lambda t: t["foliage"])
    elif e.canopy_share is not None and len(foliage) and foliage.mean() >= e.canopy_share:
        # a wooded tile in urban mode: the same, measured (foliage is most of the scene)
        choices["canopy"] = float(foliage.mean())
        steps[-1] = ("vegetation", L.VEGETATION, lambda t: t["foliage"])
    for name, code, step in steps:
        if len(idx):
            if name == "buildings":
                (hit, _), _ = side_by_side(lambda: step(pt), prepare)  # noqa: B023 (called here)
            else:
                hit = step(pt)
            labels[idx[hit]] = code
            keep = np.flatnonzero(~hit)
            idx = idx[keep]
            pt = {k: _take_rows(a, keep) if a.ndim == 2 else np.take(a, keep) for k, a in pt.items()}
        clock.lap(name)
    return labels, segment, density, vert
