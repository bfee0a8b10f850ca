"""The cloud's own density, and the Sec. 3.1 outlier threshold and voxel sizes taken relative
to it (paper 004).

The paper's figures (0.33 m density voxels, 100 points/m^3, 0.2 m normals, 0.5 m terrain
cells) are mobile-mapping figures: on an airborne tile of 2-10 points/m^2 a 0.33 m voxel's
3x3x3 neighbourhood holds one or two points and every point falls under 100 points/m^3.
Here every size is taken from the cloud's **surface density** rho (points per m^2 of the
surfaces scanned, a robust median over the points of the tile): a neighbourhood of side
``3 v`` on a surface holds about ``rho (3 v)^2`` points, so ``v = sqrt(n / rho) / 3`` gives it
``n`` points; the paper's sizes stay the lower bounds, so dense (mobile-mapping) clouds keep
them. The outlier threshold is then a share of a low percentile of the cloud's own point
densities (the paper's Sec. 4: "a local point density significantly lower than the average"),
with a floor of a few points per neighbourhood; ``relative = False`` keeps the paper's
absolute threshold.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from prc_slam.util.threads import side_by_side
from prc_slam.util.voxels import voxel_counts


def surface_density(points: np.ndarray, voxel: float = 1.0, min_count: float = 8.0) -> float:
    """Points per m^2 of scanned surface: the median over the points of the count in their
    ``voxel`` cube divided by ``voxel^2`` (a surface crossing a cube leaves ~ rho v^2 points in
    it). Where that median holds fewer than ``min_count`` points, it is measured again in cubes
    big enough to hold them (up to 8 m)."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        return 0.0
    rho = 0.0
    for _ in range(3):
        counts, _ = side_by_side(*(partial(voxel_counts, pts, voxel, offset=shift) for shift in (0.0, 0.5 * voxel)))
        count = max(0.0, *(point_median(c) for c in counts))
        rho = count / voxel**2
        if count >= min_count or voxel >= 8.0:
            break
        voxel = float(min(8.0, np.sqrt(min_count / max(rho, 1e-9)) * 1.2))
    return rho


def point_median(counts: np.ndarray) -> float:
    """``np.median(counts[grid.voxel])``, the median over the points of their voxel's count,
    from the histogram of the counts (each voxel's count appears that many times) instead of
    a sort of the points: the same value."""
    counts = np.asarray(counts, dtype=np.int64)
    weight = np.bincount(counts, weights=counts.astype(np.float64)).astype(np.int64)
    total = int(weight.sum())
    if total == 0:
        return float("nan")
    cum = np.cumsum(weight)
    lo = int(np.searchsorted(cum, (total - 1) // 2, side="right"))  # value of sorted[(n-1)//2]
    hi = int(np.searchsorted(cum, total // 2, side="right"))  # value of sorted[n//2]
    return float(np.mean([lo, hi]))


def size_for(rho: float, points_in_neighbourhood: float, floor: float) -> float:
    """Voxel side whose 3x3x3 neighbourhood holds ``points_in_neighbourhood`` points of a
    surface of density ``rho`` (never below ``floor``, the paper's size)."""
    if rho <= 0:
        return floor
    return float(max(floor, np.sqrt(points_in_neighbourhood / rho) / 3.0))


@dataclass
class DensityScale:
    """Sizes and the outlier threshold used on one cloud (or tile).

    Attributes
    ----------
    rho : float
        Surface density (points/m^2), :func:`surface_density`.
    density_voxel, normal_voxel, ground_cell : float
        Sec. 3.1 voxel, normals/segmentation voxel, Sec. 4.1 terrain cell (m).
    threshold : float
        Points/m^3 under which a point is an outlier.
    relative : bool
        Whether the sizes and threshold follow the cloud (False: the paper's fixed values).
    """

    rho: float
    density_voxel: float
    normal_voxel: float
    ground_cell: float
    threshold: float = 0.0
    relative: bool = True

    def factor(self, paper_voxel: float) -> float:
        """How much coarser than the paper's density voxel this cloud's is (>= 1)."""
        return self.density_voxel / paper_voxel


def outlier_threshold(
    density: np.ndarray, voxel: float, percentile: float, fraction: float, min_points: float
) -> float:
    """Relative Sec. 3.1 threshold: ``fraction`` of the ``percentile``-th percentile of the
    point densities, at least ``min_points`` points in the 3x3x3 neighbourhood.

    The percentile is taken over the points with company (at least ``min_points`` in their
    neighbourhood, the floor itself): the reference is then the density of the scanned surfaces
    and not the outliers' own. Taken over every point it followed the outliers as soon as they
    were more than ``percentile`` % of the cloud: a simulated mobile map with 5 % outliers per
    sweep (6 % of its points) had a 5th percentile of one point, kept 19 % of its outliers at
    the floor, and its ground grid took the minimum of the outliers under the road (ground
    recall 0.00)."""
    floor = min_points / (27.0 * voxel**3)
    density = np.asarray(density)
    dense = density[density >= floor * (1 - 1e-9)] if floor > 0 else density  # the floor's count itself
    if len(dense) == 0:
        return floor
    return float(max(fraction * np.percentile(dense, percentile), floor))


def below_message(share: float, threshold: float, median: float, relative: bool, paper_threshold: float) -> str:
    """The message for a cloud of which ``share`` falls under the density threshold."""
    head = (
        f"{100 * share:.1f} % of the points lie below the Sec. 3.1 density threshold of {threshold:.3g} points/m^3 "
        f"(median density {median:.3g} points/m^3) and are labelled noise"
    )
    if relative:
        return head + ": the cloud is too sparse or too uneven for its own threshold; check the input's density"
    return (
        head + f": the paper's fixed {paper_threshold:g} points/m^3 is a mobile-mapping figure; without --paper "
        "the threshold follows the cloud's own density"
    )
