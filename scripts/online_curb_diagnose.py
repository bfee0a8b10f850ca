"""Where the online curb labels go wrong: per input, curb point precision / recall / F1, the true class of
the false curb returns, the label the missed curb returns got, and per range band the curb returns found.

``--before`` runs the curb steps as they were before they were scaled to the beam spacing (the column's
steps in metres, Sec. 6 regions on every beam spacing); ``--face name=value`` sets a keyword of
:func:`prc_slam.online.spinning.detect_curbs_spinning`.

    .venv/bin/python scripts/online_curb_diagnose.py /tmp/prc_slam_street/hdl32_s{0,1,2} --max-frames 3 [--before]
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam import labels as L
from prc_slam.jobs.common import open_input
from prc_slam.online import OnlineDetector
from prc_slam.online.curb import CurbParams

BANDS_M = (10.0, 20.0, 30.0, 40.0)


def diagnose(path: Path, detector: OnlineDetector, max_frames: int | None) -> dict[str, Any]:
    """Curb confusion of ``detector`` over ``path`` (true curb: the reference labels)."""
    dataset, n = open_input(path, max_frames=max_frames)
    tp = fp = fn = 0
    fp_truth, fn_label = Counter(), Counter()
    bands = np.zeros((3, len(BANDS_M) + 1), int)  # true curb, found, labelled curb
    for i in range(n):
        scan = dataset[i]
        if scan.gt_labels is None:
            raise SystemExit(f"{path}: no reference labels")
        labels = detector.process(scan).labels
        true = (scan.gt_labels == L.CURB) & scan.valid
        said = (labels == L.CURB) & scan.valid
        tp += int((true & said).sum())
        fp += int((said & ~true).sum())
        fn += int((true & ~said).sum())
        fp_truth.update(L.CODE_TO_NAME.get(int(c), str(c)) for c in scan.gt_labels[said & ~true])
        fn_label.update(L.CODE_TO_NAME.get(int(c), str(c)) for c in labels[true & ~said])
        xyz = scan.slot_xyz()
        band = np.searchsorted(BANDS_M, np.hypot(xyz[..., 0], xyz[..., 1]), side="right")
        for k, m in enumerate((true, true & said, said)):
            bands[k] += np.bincount(band[m], minlength=len(BANDS_M) + 1)
    p = tp / max(tp + fp, 1)
    r = tp / max(tp + fn, 1)
    return {
        "precision": p, "recall": r, "f1": 2 * p * r / max(p + r, 1e-12), "false_truth": fp_truth,
        "missed_label": fn_label, "bands": bands,
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("inputs", nargs="+", type=Path)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--before", action="store_true", help="the curb steps before the beam-spacing scaling")
    ap.add_argument("--face", action="append", default=[], metavar="NAME=VALUE", help="detect_curbs_spinning keyword")
    args = ap.parse_args()
    faces: dict[str, Any] = {"relative": False, "top_tol": -1.0} if args.before else {}
    for item in args.face:
        k, _, v = item.partition("=")
        flag = v.lower() in ("true", "false")  # relative; every other keyword is a number
        faces[k] = v.lower() == "true" if flag else float(v)
    curb = CurbParams(max_spacing=float("inf")) if args.before else None
    edges = ["0"] + [f"{b:g}" for b in BANDS_M]
    for path in args.inputs:
        d = diagnose(path, OnlineDetector(curb=curb, curb_faces=faces), args.max_frames)
        print(f"== {path}: curb P {d['precision']:.3f} R {d['recall']:.3f} F1 {d['f1']:.3f}")
        print(f"   false curb returns, true class: {dict(d['false_truth'].most_common(5))}")
        print(f"   missed curb returns, labelled: {dict(d['missed_label'].most_common(5))}")
        cells = [f"{e}+ m {d['bands'][1][k]}/{d['bands'][0][k]} ({d['bands'][2][k]})" for k, e in enumerate(edges)]
        print("   found / true (labelled curb) by range: " + ", ".join(cells))


if __name__ == "__main__":
    main()
