"""Odometry acceptance on drives nobody tuned on: one ``prc-slam compare`` per seed (all variants
in one run), then the tables.

Sections (``--only``, comma-separated; default all, in this order):

- ``corridor``: simulated hdl64 road tunnel; the share of the frames beyond the entrance's reach
  (``x > structured + odometry max range``) flagged degenerate along the axis, and the ATE with
  and without keeping the prediction along it (two runs: ``odometry.degeneracy.keep_prediction``);
- ``urban``: simulated urban hdl64 drives, deskewing on: prc ATE and time over raw's,
  prc+classaware ATE over prc's, frames flagged degenerate;
- ``forest``: simulated forest walks (vlp16, wind 0.3, ``--mode forest``): prc+classaware ATE over
  prc's, sweeps matched class-aware, frames flagged;
- ``kitti``: KITTI 00 frames 0-15 with and without the degeneracy handling.

Every heavy step runs niced (``nice -n 15``) one at a time; simulations and compare outputs are
kept under ``--work`` and reused, so an interrupted run resumes. Example::

    .venv/bin/python scripts/odometry_acceptance.py --work /tmp/odo_acc --urban-seeds 100-109 \\
        --forest-seeds 100-104 --corridor-seeds 0,1
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

PRC_SLAM = str(Path(sys.executable).with_name("prc-slam"))
NICE = ["nice", "-n", "15"]
#: the corridor scene's entrance (data_tools.sim.corridor.CorridorParams.structured) and the
#: odometry's default range: frames farther than both from the entrance see no cross-structure
STRUCTURED, REACH = 60.0, 100.0


def seeds(text: str) -> list[int]:
    """``"100-104"`` or ``"1,3,5"``."""
    if not text:
        return []
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def run(cmd: list[str], log: Path) -> None:
    with log.open("w") as f:
        done = subprocess.run([*NICE, *cmd], stdout=f, stderr=subprocess.STDOUT, check=False)
    if done.returncode:
        raise SystemExit(f"failed ({done.returncode}): {' '.join(cmd)}; see {log}")


def simulate(work: Path, name: str, args: list[str]) -> Path:
    out = work / "sims" / name
    if not (out / "poses.txt").exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        run([PRC_SLAM, "simulate", "--out", str(out), *args], work / f"{name}.simulate.log")
    return out


def compare(work: Path, name: str, data: Path, args: list[str]) -> dict:
    out = work / "runs" / name
    if not (out / "metrics.json").exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        run([PRC_SLAM, "compare", str(data), "--out", str(out), *args], work / f"{name}.compare.log")
    return json.loads((out / "metrics.json").read_text())


def config(work: Path, name: str, text: str) -> Path:
    path = work / f"{name}.yaml"
    path.write_text(text)
    return path


def flagged(v: dict) -> int:
    return len({d["frame"] for d in v.get("degenerate_frames", [])})


def ratio(a: float | None, b: float | None) -> float:
    return float("nan") if a is None or b is None or not b else a / b


def corridor(work: Path, frames: int, seed_list: list[int]) -> None:
    off = config(work, "keep_off", "odometry:\n  degeneracy:\n    keep_prediction: false\n")
    print("\n## Corridor (hdl64 road tunnel, one compare per seed and setting)\n")
    print("| seed | variant | featureless frames | flagged along the axis | flagged elsewhere | ATE kept / not (m) |")
    print("|---|---|---|---|---|---|")
    for seed in seed_list:
        data = simulate(work, f"corridor{seed}", ["--scene", "corridor", "--frames", str(frames), "--seed", str(seed)])
        on = compare(work, f"corridor{seed}", data, ["--variants", "raw,prc"])
        no = compare(work, f"corridor{seed}_keep_off", data, ["--variants", "raw,prc", "--config", str(off)])
        x = np.loadtxt(data / "poses.txt", ndmin=2)[:, 3]
        stretch = np.flatnonzero(x > STRUCTURED + REACH)
        for name, v in on["variants"].items():
            axis = {
                d["frame"]
                for d in v["degenerate_frames"]
                if d["kind"] == "translation" and abs(d["direction"][0]) > 0.9
            }
            other = {d["frame"] for d in v["degenerate_frames"]} - set(stretch.tolist())
            hit = sum(int(i) in axis for i in stretch)
            print(
                f"| {seed} | {name} | {len(stretch)} | {hit} ({100 * hit / max(len(stretch), 1):.1f} %) | "
                f"{len(other)} | {v['ate_rmse_m']:.3f} / {no['variants'][name]['ate_rmse_m']:.3f} |"
            )


def urban(work: Path, frames: int, seed_list: list[int]) -> None:
    print("\n## Urban hdl64 drives (deskew on, one compare per seed: raw, prc, prc+classaware)\n")
    print(
        "| seed | ATE raw (m) | prc / raw ATE | prc / raw time | classaware / prc ATE | classaware sweeps | flagged |"
    )
    print("|---|---|---|---|---|---|---|")
    ate, tim, ca = [], [], []
    for seed in seed_list:
        data = simulate(work, f"urban{seed}", ["--frames", str(frames), "--seed", str(seed)])
        v = compare(work, f"urban{seed}", data, ["--variants", "raw,prc,prc+classaware"])["variants"]
        raw, prc, cls = v["raw"], v["prc"], v["prc+classaware"]
        ate.append(ratio(prc["ate_rmse_m"], raw["ate_rmse_m"]))
        tim.append(ratio(prc["ms_per_frame"], raw["ms_per_frame"]))
        ca.append(ratio(cls["ate_rmse_m"], prc["ate_rmse_m"]))
        print(
            f"| {seed} | {raw['ate_rmse_m']:.4f} | {ate[-1]:.3f} | {tim[-1]:.3f} | {ca[-1]:.3f} | "
            f"{len(cls.get('classaware_frames', []))} of {cls['frames']} | "
            f"{flagged(raw)} / {flagged(prc)} of {raw['frames']} |"
        )
    if ate:
        print(
            f"\nprc/raw ATE median {statistics.median(ate):.3f}, worst {max(ate):.3f}; prc/raw time median "
            f"{statistics.median(tim):.3f}; classaware/prc ATE median {statistics.median(ca):.3f} ({len(ate)} seeds)"
        )


def forest(work: Path, frames: int, seed_list: list[int]) -> None:
    print("\n## Forest walks (vlp16, wind 0.3, --mode forest, one compare per seed: raw, prc, prc+classaware)\n")
    print("| seed | ATE raw / prc / classaware (m) | classaware / prc ATE | classaware sweeps | flagged |")
    print("|---|---|---|---|---|")
    ca = []
    for seed in seed_list:
        args = ["--scene", "forest", "--sensor", "vlp16", "--wind", "0.3", "--frames", str(frames), "--seed", str(seed)]
        data = simulate(work, f"forest{seed}", args)
        v = compare(work, f"forest{seed}", data, ["--mode", "forest", "--variants", "raw,prc,prc+classaware"])[
            "variants"
        ]
        raw, prc, cls = v["raw"], v["prc"], v["prc+classaware"]
        ca.append(ratio(cls["ate_rmse_m"], prc["ate_rmse_m"]))
        print(
            f"| {seed} | {raw['ate_rmse_m']:.4f} / {prc['ate_rmse_m']:.4f} / {cls['ate_rmse_m']:.4f} | {ca[-1]:.3f} | "
            f"{len(cls.get('classaware_frames', []))} of {cls['frames']} | "
            f"{flagged(raw)} / {flagged(prc)} / {flagged(cls)} of {raw['frames']} |"
        )
    if ca:
        print(f"\nclassaware/prc ATE median {statistics.median(ca):.3f} ({len(ca)} seeds)")


def kitti(work: Path, root: Path) -> None:
    off = config(work, "degeneracy_off", "odometry:\n  degeneracy:\n    enabled: false\n")
    print("\n## KITTI 00, frames 0-15 (raw, prc, prc+classaware)\n")
    print("| setting | ATE raw / prc / classaware (m) | flagged raw / prc |")
    print("|---|---|---|")
    for name, extra in (("degeneracy on (default)", []), ("degeneracy off", ["--config", str(off)])):
        tag = "kitti" if not extra else "kitti_off"
        v = compare(work, tag, root, ["--variants", "raw,prc,prc+classaware", *extra])["variants"]
        ates = " / ".join(f"{v[n]['ate_rmse_m']:.4f}" for n in ("raw", "prc", "prc+classaware"))
        print(f"| {name} | {ates} | {flagged(v['raw'])} / {flagged(v['prc'])} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/odometry_acceptance"))
    ap.add_argument("--only", default="corridor,urban,forest,kitti")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--corridor-frames", type=int, default=400)
    ap.add_argument("--urban-seeds", default="100-109")
    ap.add_argument("--forest-seeds", default="100-104")
    ap.add_argument("--corridor-seeds", default="0,1")
    ap.add_argument("--kitti", type=Path, default=Path("/work/shared/data/kitti00"))
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    only = a.only.split(",")
    if "corridor" in only:
        corridor(a.work, a.corridor_frames, seeds(a.corridor_seeds))
    if "urban" in only:
        urban(a.work, a.frames, seeds(a.urban_seeds))
    if "forest" in only:
        forest(a.work, a.frames, seeds(a.forest_seeds))
    if "kitti" in only:
        kitti(a.work, a.kitti)


if __name__ == "__main__":
    main()
