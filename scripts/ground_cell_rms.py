"""RMS misfit of the ground model's cells on a recording with truth labels and poses.

Feeds each sweep's truth-labelled ground points, at the truth pose, to
:class:`prc_slam.odometry.ground.GroundModel` with no misfit bound, then prints the percentiles of
the cells' RMS misfit about their least-squares planes: what ``odometry.ground.max_rms`` has to
admit for the ground of that recording to be matched. Usage::

    python scripts/ground_cell_rms.py SIMULATED_OR_KITTI_DIR [FRAMES]
"""

from __future__ import annotations

import argparse

import numpy as np

from data_tools.datasets import open_dataset
from prc_slam import labels as L
from prc_slam.odometry.ground import GroundConfig, GroundModel, ground_points


def cell_rms(model: GroundModel, min_points: int) -> np.ndarray:
    """RMS misfit (m) of every cell holding at least ``min_points`` points spread over both axes."""
    m = model.moments[(model.keys[:, 2] != 0) & (model.moments[:, 0] >= min_points)]
    n = m[:, 0]
    mu, mv, mz = m[:, 1] / n, m[:, 2] / n, m[:, 3] / n
    cuu, cuv, cvv = m[:, 4] / n - mu * mu, m[:, 5] / n - mu * mv, m[:, 6] / n - mv * mv
    cuz, cvz, czz = m[:, 7] / n - mu * mz, m[:, 8] / n - mv * mz, m[:, 9] / n - mz * mz
    det = cuu * cvv - cuv * cuv
    tr = cuu + cvv
    spread = 0.5 * (tr - np.sqrt(np.maximum(tr * tr - 4.0 * det, 0.0)))  # across the points' main direction
    ok = (det > 0) & (spread >= (0.15 * model.config.cell) ** 2)  # as the model's fit: not along one line
    a = (cuz * cvv - cvz * cuv)[ok] / det[ok]
    b = (cvz * cuu - cuz * cuv)[ok] / det[ok]
    return np.sqrt(np.maximum(czz[ok] - (a * cuz[ok] + b * cvz[ok]), 0.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", help="a recording with truth labels and poses (simulated or KITTI)")
    ap.add_argument("frames", nargs="?", type=int, default=60)
    a = ap.parse_args()
    ds = open_dataset(a.data)
    config = GroundConfig(max_rms=1e9)
    model = GroundModel(config, max_range=1e9)  # keep every cell
    for i in range(min(a.frames, len(ds))):
        scan = ds[i]
        labels = scan.reference_labels()
        if labels is None or scan.gt_pose is None:
            raise SystemExit(f"{a.data}: frame {i} has no truth labels or pose")
        model.update(ground_points(scan.points().astype(np.float64), labels, [L.GROUND], 0.5, 40.0), scan.gt_pose)
    rms = cell_rms(model, config.min_points)
    p = np.percentile(rms, [10, 50, 90, 99]) * 1000
    print(
        f"{a.data}: {len(rms)} cells; RMS misfit (mm) p10 {p[0]:.0f}, median {p[1]:.0f}, p90 {p[2]:.0f}, p99 {p[3]:.0f}"
    )
    for bound in (0.05, 0.10):
        print(f"  cells within {bound * 100:.0f} cm: {np.mean(rms <= bound):.2f}")


if __name__ == "__main__":
    main()
