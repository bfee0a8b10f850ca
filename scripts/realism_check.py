"""Realism check of the simulator: KISS-ICP on a simulated hdl64 urban drive, and the
class mix of a simulated frame beside the labelled KITTI frames.

    .venv/bin/python scripts/realism_check.py --frames 200 --out out/realism

Writes ``out/realism/realism.json`` and prints the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from data_tools import open_dataset
from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L
from prc_slam.evaluation.metrics import ate_rmse, kitti_errors

CLASSES = [L.GROUND, L.CURB, L.BUILDING, L.VEGETATION, L.TRUNK, L.VEHICLE, L.POLE, L.NOISE, L.UNCLASSIFIED]
KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti00"


def class_mix(codes: np.ndarray) -> dict[str, float]:
    return {L.CODE_TO_NAME[c]: round(float(np.mean(codes == c)), 4) for c in CLASSES}


def kiss_icp_run(seq) -> tuple[np.ndarray, float]:
    """Default KISS-ICP (voxel size = max_range / 100) with per-point deskewing timestamps."""
    for key in [k for k in os.environ if k.lower().startswith("kiss_icp_")]:
        os.environ.pop(key)  # KISSConfig reads kiss_icp_* variables
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    odom = KissICP(load_config(None))
    poses = []
    t0 = time.perf_counter()
    for scan in seq:
        pts = scan.points().astype(np.float64)
        t = scan.point_times()
        stamps = (t - t.min()) / max(float(t.max() - t.min()), 1e-9)
        odom.register_frame(pts, stamps)
        poses.append(odom.last_pose.copy())
    return np.array(poses), (time.perf_counter() - t0) / len(seq)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("out/realism"))
    args = ap.parse_args()
    root = args.out / f"hdl64_urban_{args.frames}_seed{args.seed}"
    t0 = time.perf_counter()
    sim = Simulator(SimConfig(scene="urban", sensor="hdl64", frames=args.frames, seed=args.seed))
    if not (root / "sim.json").is_file():
        write_sequence(sim, root)
    sim_seconds = time.perf_counter() - t0
    seq = open_dataset(root)
    est, ms = kiss_icp_run(seq)
    gt = seq.poses
    est_world = gt[0] @ est  # KISS-ICP starts at the identity
    t_err, r_err = kitti_errors(est_world, gt)
    dist = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    sim_mix = class_mix(np.concatenate([seq[i].gt_labels[seq[i].valid] for i in range(0, len(seq), 20)]))
    result = {
        "frames": len(seq),
        "path_length_m": dist,
        "simulate_seconds": sim_seconds,
        "kiss_icp_ms_per_frame": ms * 1e3,
        "kitti_trans_pct": t_err,
        "kitti_rot_deg_per_m": r_err,
        "ate_rmse_m": ate_rmse(est_world, gt),
        "class_mix_simulated": sim_mix,
    }
    if (KITTI / "labels").is_dir():
        kitti = open_dataset(KITTI)
        result["class_mix_kitti_frames_0_2"] = class_mix(
            np.concatenate([kitti[i].reference_labels() for i in range(3)])
        )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "realism.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
