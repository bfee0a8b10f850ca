"""Each spinning car / ground parameter's effect across the simulated spinning sensors (docs/online-sensitivity.md).

One setting changed at a time from the defaults, on the street seeds the parameters were chosen on;
per sensor: vehicle instances found within 20 m and at 20-30 m (all seeds pooled), vehicle point
precision and the worst share of vehicle points labelled vegetation in a band up to 40 m (pooled).

    .venv/bin/python scripts/online_sensitivity.py --seeds 1 2 --sim-dir /tmp/prc_slam_street > /tmp/sens.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from online_acceptance import SENSORS, score, simulated

from prc_slam.online import OnlineDetector
from prc_slam.online.spinning import SpinningCarParams

#: (label, OnlineDetector keyword arguments): the defaults, then one change each
SETTINGS: list[tuple[str, dict[str, Any]]] = [
    ("defaults", {}),
    ("top_width 0 (every top on the highest beam goes on upward)", {"spinning": {"top_width": 0.0}}),
    ("top_height 2.6 (tall tops on the highest beam no evidence)", {"spinning": {"top_height": 2.6}}),
    ("high_steep off", {"spinning": {"high_steep": False}}),
    ("min_thickness 0.15 -> 0.05", {"spinning": {"min_thickness": 0.05}}),
    ("max_bottom 0.5 -> 0.8", {"spinning": {"max_bottom": 0.8}}),
    ("min_ring_triples 3 -> 1", {"spinning": {"min_ring_triples": 1}}),
    ("max_roughness 0.35 -> 0.5", {"spinning": {"max_roughness": 0.5}}),
    ("veg_resolution 0.2 -> 0 (the share over every return)", {"spinning": {"veg_resolution": 0.0}}),
    ("veg_resolution 0.2 -> 0.3", {"spinning": {"veg_resolution": 0.3}}),
    ("max_vegetation 0.5 -> 0.7", {"spinning": {"max_vegetation": 0.7}}),
    ("vegetation_gap 0.25 -> 1.0 (baselined share on every sensor)", {"spinning": {"vegetation_gap": 1.0}}),
    ("max_top 2.3 -> 2.6", {"spinning": {"max_top": 2.6}}),
    ("column_ground_all off", {"column_ground_all": False}),
]


def detector(kw: dict[str, Any]) -> OnlineDetector:
    kw = dict(kw)
    sp = SpinningCarParams(**kw.pop("spinning", {}))
    return OnlineDetector(spinning=sp, **kw)


def pooled(metrics: list[dict[str, Any]]) -> dict[str, float | None]:
    """Found shares within 20 m and at 20-30 m, point precision, worst vegetation share, ground F1."""
    found = {"0-20": [0, 0], "20-30": [0, 0]}
    tp = pred = 0
    veg: dict[str, list[int]] = {}
    g = []
    for m in metrics:
        vb = m["vehicle_by_range"]
        found["0-20"][0] += vb["within_20"]["found"]
        found["0-20"][1] += vb["within_20"]["present"]
        for r in vb["bands"]:
            if r["band"] == "20-30":
                found["20-30"][0] += r["found"]
                found["20-30"][1] += r["present"]
            if r["band"] != "40+":
                v = veg.setdefault(r["band"], [0, 0])
                v[0] += round((r["vegetation_share"] or 0) * r["points"])
                v[1] += r["points"]
        pc = m["per_class"].get("vehicle", {})
        s = pc.get("support", 0)
        if pc.get("precision") is not None and pc.get("recall"):
            t = pc["recall"] * s
            tp += t
            pred += t / pc["precision"] if pc["precision"] > 0 else 0
        g.append(m["per_class"].get("ground", {}).get("f1") or 0.0)
    return {
        "found_0_20": found["0-20"][0] / max(found["0-20"][1], 1),
        "found_20_30": found["20-30"][0] / max(found["20-30"][1], 1),
        "precision": tp / pred if pred else None,
        "vegetation_max": max(a / b for a, b in veg.values() if b) if veg else None,
        "ground_f1": sum(g) / len(g) if g else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sensors", nargs="+", default=list(SENSORS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--sim-dir", type=Path, default=Path("/tmp/prc_slam_street"))
    args = ap.parse_args()
    paths = {s: [simulated(args.sim_dir, s, seed, args.frames) for seed in args.seeds] for s in args.sensors}
    print("Cells: vehicles found within 20 m / at 20-30 m; vehicle point precision; worst share of vehicle points")
    print("labelled vegetation in a band up to 40 m; mean ground F1.\n")
    print("| setting | " + " | ".join(args.sensors) + " |")
    print("|---|" + "---|" * len(args.sensors))
    for label, kw in SETTINGS:
        cells = []
        for sensor in args.sensors:
            r = pooled([score(p, detector(kw)) for p in paths[sensor]])
            cells.append(
                f"{r['found_0_20']:.2f} / {r['found_20_30']:.2f}; {r['precision'] or 0:.3f}; "
                f"{r['vegetation_max'] or 0:.2f}; {r['ground_f1'] or 0:.2f}"
            )
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
