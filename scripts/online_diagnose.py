"""Why the spinning car detector misses vehicles: per missed instance, the step that drops it.

For every reference vehicle instance of a frame (>= 20 returns) that is not found (under half of its
returns labelled vehicle), by range band: the share of its returns that never became candidates
(ground, under ``min_above_ground``, over ``max_height``), and for the candidate segment holding most
of its returns, which tests of step 4-6 (:mod:`prc_slam.online.spinning`) it fails; also the share of
its returns the coarse classifier calls vegetation (the label they keep when they are no car).

    .venv/bin/python scripts/online_diagnose.py /tmp/st/hdl64_s1 [/tmp/st/vlp16_s1 ...] [--max-frames N]
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np

from prc_slam import labels as L
from prc_slam.evaluation.scoring import RANGE_BANDS_M, band_name
from prc_slam.jobs.common import open_input
from prc_slam.online import OnlineDetector
from prc_slam.online.spinning import SpinningCarParams


def failed_tests(f: dict[str, np.ndarray], k: int, p: SpinningCarParams) -> list[str]:
    """The step 4-6 tests segment ``k`` fails (``f``: the detector's per-segment features)."""
    tests = {
        "points": f["points"][k] >= p.min_points,
        "roof": f["roof"][k] >= p.min_top,
        "top90": f["top90"][k] <= p.max_top,
        "bottom": f["bottom"][k] <= p.max_bottom,
        "length": p.min_length <= f["length"][k] <= p.max_length,
        "width": f["width"][k] <= p.max_width,
        "thickness": f["thickness"][k] >= p.min_thickness,
        "high_share": f["high_share"][k] <= p.high_share,
        "roughness": f["roughness"][k] <= p.max_roughness,
        "ring_triples": f["ring_triples"][k] >= p.min_ring_triples,
        "vegetation": f["vegetation"][k] <= p.max_vegetation,
    }
    return [name for name, ok in tests.items() if not ok]


def diagnose(path: Path, max_frames: int | None, detector: OnlineDetector) -> tuple[Counter, Counter, list[dict]]:
    """Per band: present / missed counts and the reasons of the misses; one record per missed instance."""
    dataset, n = open_input(path, max_frames=max_frames)
    present, reasons, records = Counter(), Counter(), []
    p = detector.spinning_params
    for i in range(n):
        scan = dataset[i]
        res = detector.process(scan)
        cars = getattr(detector, "last_cars", None)
        xyz = scan.slot_xyz()
        veh = scan.gt_labels == L.VEHICLE
        for inst in np.unique(scan.gt_instance[veh]):
            m = veh & (scan.gt_instance == inst)
            cnt = int(m.sum())
            if cnt < 20:
                continue
            c = xyz[m].mean(axis=0)
            dist = float(np.hypot(c[0], c[1]))
            band = next((band_name(lo, hi) for lo, hi in RANGE_BANDS_M if lo <= dist < hi), "?")
            present[band] += 1
            lab = res.labels[m]
            if np.mean(lab == L.VEHICLE) >= 0.5:
                continue
            rec = {"frame": i, "instance": int(inst), "dist": dist, "points": cnt, "band": band}
            rec["labelled"] = {L.CODE_TO_NAME.get(int(k), str(k)): float(np.mean(lab == k)) for k in np.unique(lab)}
            rec["coarse_vegetation"] = float(np.mean(res.coarse.codes[m] == L.VEGETATION))
            why = []
            if cars is not None and cars.segments is not None:
                seg = cars.segments[m]
                rec["no_candidate"] = float(np.mean(seg == 0))
                ids, counts = np.unique(seg[seg > 0], return_counts=True)
                if len(ids):
                    k = int(ids[np.argmax(counts)])
                    rec["segment_share"] = float(counts.max() / cnt)
                    why = failed_tests(cars.features, k, p)
                    rec["features"] = {name: float(v[k]) for name, v in cars.features.items()}
                    if not why:
                        why = ["accepted segment, too small a share"]
                else:
                    why = ["no candidate segment"]
                if rec["no_candidate"] > 0.5:
                    why = ["mostly no candidate", *why]
            rec["why"] = why
            for w in why:
                reasons[(band, w)] += 1
            records.append(rec)
    return present, reasons, records


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("inputs", nargs="+", type=Path)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--paper", action="store_true", help="OnlineDetector.paper()")
    ap.add_argument("--verbose", action="store_true", help="one line per missed instance")
    args = ap.parse_args()
    for path in args.inputs:
        detector = OnlineDetector.paper() if args.paper else OnlineDetector()
        present, reasons, records = diagnose(path, args.max_frames, detector)
        missed = Counter(r["band"] for r in records)
        print(f"== {path}")
        for lo, hi in RANGE_BANDS_M:
            b = band_name(lo, hi)
            if not present[b]:
                continue
            why = ", ".join(f"{w} {c}" for (bb, w), c in reasons.most_common() if bb == b)
            veg = [r["labelled"].get("vegetation", 0.0) for r in records if r["band"] == b]
            print(
                f"  {b:>6} m: missed {missed[b]} of {present[b]}; mean share labelled vegetation of the missed "
                f"{np.mean(veg) if veg else 0:.2f}; tests failed: {why}"
            )
        if args.verbose:
            for r in records:
                f = r.get("features", {})
                feats = " ".join(f"{k}={v:.2f}" for k, v in f.items())
                lab = " ".join(f"{k}={v:.2f}" for k, v in sorted(r["labelled"].items(), key=lambda kv: -kv[1])[:3])
                print(
                    f"    f{r['frame']} #{r['instance']} {r['dist']:.1f} m {r['points']} pts; {lab}; "
                    f"no_cand={r.get('no_candidate', 0):.2f} seg={r.get('segment_share', 0):.2f}; "
                    f"{'/'.join(r['why'])}; {feats}"
                )


if __name__ == "__main__":
    main()
