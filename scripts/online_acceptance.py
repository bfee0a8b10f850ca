"""The online detectors' acceptance table: simulated streets, seeds x sensors x range bands.

For every simulated spinning sensor and seed (``prc-slam simulate --scene street``, made under
``--sim-dir`` when missing) and, with ``--kitti``, KITTI 00 frames 0-2: vehicle instances found
and point precision / recall / share labelled vegetation per range band (``prc_slam.evaluation.scoring``),
online ground and curb F1, and whether each criterion holds. ``--set name=value`` overrides a
``SpinningCarParams`` field (the sensitivity table of docs/online-sensitivity.md); ``--paper``
runs ``OnlineDetector.paper()``.

    .venv/bin/python scripts/online_acceptance.py --seeds 3 4 5 --kitti ../shared/data/kitti00 --json /tmp/acc.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from prc_slam.evaluation.scoring import InstanceBands, OnlineScorer
from prc_slam.jobs.common import open_input
from prc_slam.online import CoarseParams, CurbParams, OnlineDetector
from prc_slam.online.spinning import SpinningCarParams
from prc_slam.pipeline import Pipeline

SENSORS = ("hdl64", "hdl32", "vlp16", "os1-64", "os0-128", "os2-128")
#: sensors the ground / curb criteria apply to (vlp16 curbs are reported only)
GROUND_CURB_SENSORS = ("hdl64", "hdl32", "os1-64", "os0-128", "os2-128")


def simulated(sim_dir: Path, sensor: str, seed: int, frames: int) -> Path:
    """The street drive of ``sensor`` and ``seed`` under ``sim_dir`` (simulated when missing)."""
    out = sim_dir / f"{sensor}_s{seed}"
    if not (out / "sim.json").exists():
        cmd = [sys.executable, "-m", "prc_slam", "simulate", "--scene", "street", "--sensor", sensor,
               "--frames", str(frames), "--seed", str(seed), "--out", str(out)]  # fmt: skip
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return out


def make_detector(paper: bool, overrides: dict[str, Any], coarse: dict[str, Any] | None = None) -> OnlineDetector:
    """The default detector (or the paper's) with ``SpinningCarParams`` (and ``CoarseParams``) fields overridden."""
    if paper:
        return OnlineDetector.paper()
    cp = CoarseParams(**coarse) if coarse else None
    return OnlineDetector(coarse=cp, spinning=dataclasses.replace(SpinningCarParams(), **overrides))


def parse_overrides(items: list[str], cls: type, ap: argparse.ArgumentParser) -> dict[str, Any]:
    """``name=value`` strings as field values of the dataclass ``cls`` (typed as its defaults)."""
    out: dict[str, Any] = {}
    defaults = cls()
    for item in items:
        k, _, v = item.partition("=")
        if not hasattr(defaults, k):
            ap.error(f"no {cls.__name__} field {k!r}")
        d = getattr(defaults, k)
        out[k] = v.lower() in ("1", "true", "yes") if isinstance(d, bool) else type(d)(v)
    return out


def score(path: Path, detector: OnlineDetector, max_frames: int | None = None) -> dict[str, Any]:
    """The ``detect`` metrics of ``detector`` over ``path``."""
    dataset, n = open_input(path, max_frames=max_frames)
    scorer = OnlineScorer()
    result = Pipeline(online=detector, sinks=[scorer]).run(dataset[i] for i in range(n))
    return scorer.metrics(result)


def summary(m: dict[str, Any]) -> dict[str, Any]:
    """The acceptance figures of one run's metrics."""
    pc = m.get("per_class", {})
    bands = {r["band"]: r for r in m["vehicle_by_range"]["bands"]}
    veh = pc.get("vehicle", {})
    return {
        "found_0_20": m["vehicle_by_range"]["within_20"],
        "bands": bands,
        "vehicle_p": veh.get("precision"),
        "vehicle_r": veh.get("recall"),
        "ground_f1": pc.get("ground", {}).get("f1"),
        "curb_f1": pc.get("curb", {}).get("f1"),
        "vegetation_max": max((r["vegetation_share"] or 0.0) for b, r in bands.items() if b != "40+"),
    }


#: the configuration before the range-noise rules (``noise_labels``, ``ring_labels``, ``vegetation_noise``) and
#: step 5's roof allowance across missing returns (``missing_top``)
NO_NOISE_RULES: dict[str, Any] = dict(
    noise_labels=False, ring_labels=False, spinning=SpinningCarParams(vegetation_noise=False, missing_top=False)
)
#: the configuration before the work across sensors: Sec. 5 (a) ground on spinning sensors, every top on the
#: highest beam going on upward, any high return, the vegetation share over every return, and none of the
#: beam-spacing or range-noise rules (curb faces in metres, no spacing bound on Sec. 6 regions, step 5's bottom
#: from the return itself)
BEFORE: dict[str, Any] = dict(
    column_ground_all=False,
    noise_labels=False,
    ring_labels=False,
    curb=CurbParams(max_spacing=float("inf")),
    curb_faces={"relative": False, "top_tol": -1},
    spinning=SpinningCarParams(
        top_width=0.0, high_steep=False, veg_resolution=0.0, bottom_gap=False, vegetation_noise=False, missing_top=False
    ),
)


def speed(frames: int = 10, rounds: int = 8) -> dict[str, float]:
    """Points per second of the default detector, of it without the range-noise rules and the
    missing-return roof allowance (:data:`NO_NOISE_RULES`) and of the configuration before the work
    across sensors (:data:`BEFORE`) on the bench's simulated hdl64 urban sweeps
    (``prc_slam.jobs.bench.bench_online``), alternating in one process; each figure the best of
    ``rounds``."""
    import time

    import numpy as np

    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.scan import Scan

    sim = Simulator(SimConfig(scene="urban", sensor="hdl64", frames=frames + 1))
    ranges = [sim.frame(i).ranges for i in range(frames + 1)]
    model = sim.sensor.model
    configs: dict[str, dict[str, Any]] = {"default": {}, "no_noise_rules": NO_NOISE_RULES, "before": BEFORE}
    best = dict.fromkeys(configs, np.inf)
    for _ in range(rounds):
        for name, kw in configs.items():
            scans = [Scan(r, model) for r in ranges]
            det = OnlineDetector(**kw)
            det.process(scans[0])
            t0 = time.perf_counter()
            for scan in scans[1:]:
                det.process(scan)
            best[name] = min(best[name], (time.perf_counter() - t0) / frames)
    points = float(np.mean([Scan(r, model).n_points for r in ranges[1:]]))
    return {f"{k}_points_per_s": points / v for k, v in best.items()} | {f"{k}_ms": 1e3 * v for k, v in best.items()}


#: the timing loop run in each checkout's own process by :func:`speed_against` (its imports are that
#: checkout's): the bench's hdl64 urban sweeps, then one round of the default detector per line read
SPEED_CHILD = """
import hashlib, sys, time
import numpy as np
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam.online import OnlineDetector
from prc_slam.scan import Scan
frames = int(sys.argv[1])
sim = Simulator(SimConfig(scene="urban", sensor="hdl64", frames=frames + 1))
ranges = [sim.frame(i).ranges for i in range(frames + 1)]
model = sim.sensor.model
digest = hashlib.sha256(b"".join(np.ascontiguousarray(r).tobytes() for r in ranges)).hexdigest()[:16]
print("ready", digest, flush=True)
for _ in sys.stdin:
    scans = [Scan(r, model) for r in ranges]
    det = OnlineDetector()
    det.process(scans[0])
    t0, c0 = time.perf_counter(), time.thread_time()
    for scan in scans[1:]:
        det.process(scan)
    print(1e3 * (time.perf_counter() - t0) / frames, 1e3 * (time.thread_time() - c0) / frames, flush=True)
"""


def speed_against(others: list[Path], frames: int = 10, rounds: int = 8) -> dict[str, Any]:
    """Milliseconds a sweep of the default detector of this checkout and of each checkout in ``others``
    on the bench's simulated hdl64 urban sweeps (``prc_slam.jobs.bench.bench_online``), each checkout in
    its own process with one numba thread, the processes taking turns round by round (a burst of load
    from elsewhere falls on one round of one checkout, not on one checkout's every round): per checkout
    the best round, the median and every round, in wall time and in the thread's CPU time (time spent
    waiting for a core does not count). Raises when the checkouts' sweeps differ."""
    import os
    import statistics

    here = Path(__file__).resolve().parents[1]
    trees = [here, *(Path(o).resolve() for o in others)]
    env = os.environ | {"NUMBA_NUM_THREADS": "1"}
    procs, digests = [], []
    for tree in trees:
        cmd = [sys.executable, "-c", SPEED_CHILD, str(frames)]
        p = subprocess.Popen(
            cmd, cwd=tree, env=env | {"PYTHONPATH": str(tree)}, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        procs.append(p)
    for tree, p in zip(trees, procs, strict=True):
        line = p.stdout.readline().split()
        if not line or line[0] != "ready":
            raise RuntimeError(f"{tree}: the timing process did not start")
        digests.append(line[1])
    if len(set(digests)) != 1:
        raise RuntimeError(
            f"the checkouts simulate different sweeps: {dict(zip(map(str, trees), digests, strict=True))}"
        )
    times: list[list[float]] = [[] for _ in trees]
    cpu: list[list[float]] = [[] for _ in trees]
    try:
        for _ in range(rounds + 1):  # the first round compiles (numba caches) and is left out
            for i, p in enumerate(procs):
                p.stdin.write("go\n")
                p.stdin.flush()
                wall, thread = p.stdout.readline().split()
                times[i].append(float(wall))
                cpu[i].append(float(thread))
    finally:
        for p in procs:
            p.stdin.close()
            p.wait()
    return {
        str(tree): {
            "best_ms": min(t[1:]),
            "median_ms": statistics.median(t[1:]),
            "best_cpu_ms": min(c[1:]),
            "median_cpu_ms": statistics.median(c[1:]),
            "rounds_ms": t[1:],
        }
        for tree, t, c in zip(trees, times, cpu, strict=True)
    }


def fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


def checks(name: str, sensor: str, s: dict[str, Any]) -> list[str]:
    """The criteria this run fails (empty: all hold)."""
    fails = []
    near, mid = s["found_0_20"], s["bands"]["20-30"]
    if sensor == "kitti":
        if (near["found_share"] or 0) < 0.9:
            fails.append("found 0-20 < 0.9")
        if (s["vehicle_p"] or 0) < 0.85 or (s["vehicle_r"] or 0) < 0.75:
            fails.append("P < 0.85 or R < 0.75")
        return fails
    if (near["found_share"] or 0) < 0.9:
        fails.append("found 0-20 < 0.9")
    if mid["present"] and (mid["found_share"] or 0) < 0.7:
        fails.append("found 20-30 < 0.7")
    if (s["vehicle_p"] or 0) < 0.85:
        fails.append("P < 0.85")
    if s["vegetation_max"] > 0.10:
        fails.append("vegetation > 0.10")
    if sensor in GROUND_CURB_SENSORS:
        if (s["ground_f1"] or 0) < 0.9:
            fails.append("ground F1 < 0.9")
        if (s["curb_f1"] or 0) < 0.7:
            fails.append("curb F1 < 0.7")
    return fails


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sensors", nargs="+", default=list(SENSORS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[3, 4, 5])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--sim-dir", type=Path, default=Path("/tmp/prc_slam_street"))
    ap.add_argument("--kitti", type=Path, default=None, help="KITTI 00 directory: frames 0-2 as the final check")
    ap.add_argument("--paper", action="store_true")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="SpinningCarParams override")
    ap.add_argument("--coarse", action="append", default=[], metavar="NAME=VALUE", help="CoarseParams override")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--speed", action="store_true", help="only the speed before / after, in one process")
    ap.add_argument(
        "--against",
        type=Path,
        nargs="+",
        default=None,
        metavar="DIR",
        help="with --speed: the default detector of this checkout and of each DIR (another checkout), "
        "in processes taking turns",
    )
    ap.add_argument("--rounds", type=int, default=8, help="with --speed: rounds per configuration (best taken)")
    args = ap.parse_args()
    if args.speed and args.against:
        print(json.dumps(speed_against(args.against, args.frames, args.rounds), indent=1))
        return
    if args.speed:
        print(json.dumps(speed(), indent=1))
        return
    overrides = parse_overrides(args.set, SpinningCarParams, ap)
    coarse = parse_overrides(args.coarse, CoarseParams, ap)
    runs: list[tuple[str, str, Path, int | None]] = [
        (f"{sensor} seed {seed}", sensor, simulated(args.sim_dir, sensor, seed, args.frames), None)
        for sensor in args.sensors
        for seed in args.seeds
    ]
    if args.kitti is not None:
        runs.append(("KITTI 00 frames 0-2", "kitti", args.kitti, 3))
    header = "run | 0-10 | 10-20 | 20-30 | 30-40 | found 0-20 | P | R | veg max | ground F1 | curb F1 | fails"
    print(f"| {header} |")
    print("|" + "---|" * len(header.split("|")))
    out: dict[str, Any] = {"overrides": overrides, "coarse": coarse, "paper": args.paper, "runs": {}}
    totals: dict[str, InstanceBands] = {}
    for name, sensor, path, max_frames in runs:
        m = score(path, make_detector(args.paper, overrides, coarse), max_frames)
        s = summary(m)
        fails = checks(name, sensor, s)
        b = s["bands"]
        cells = [f"{b[k]['found']}/{b[k]['present']}" for k in ("0-10", "10-20", "20-30", "30-40")]
        near = s["found_0_20"]
        print(
            f"| {name} | " + " | ".join(cells) + f" | {fmt(near['found_share'])} | {fmt(s['vehicle_p'])} | "
            f"{fmt(s['vehicle_r'])} | {s['vegetation_max']:.3f} | {fmt(s['ground_f1'])} | {fmt(s['curb_f1'])} | "
            f"{'; '.join(fails) or 'ok'} |",
            flush=True,
        )
        out["runs"][name] = {"sensor": sensor, "path": str(path), "summary": s, "fails": fails, "metrics": m}
        if sensor != "kitti":
            acc = totals.setdefault(sensor, InstanceBands())
            for k, row in enumerate(m["vehicle_by_range"]["bands"]):
                acc.counts["present"][k] += row["present"]
                acc.counts["found"][k] += row["found"]
    for sensor, acc in totals.items():
        rows = acc.to_json()
        cells = " | ".join(f"{r['found']}/{r['present']}" for r in rows["bands"][:4])
        print(f"| {sensor}, all seeds | {cells} | {fmt(rows['within_20']['found_share'])} | | | | | | |")
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
