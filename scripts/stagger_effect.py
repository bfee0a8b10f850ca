"""PRC on azimuth-aligned range images against the same sweeps staggered as Ouster sensors
stagger theirs (measurement order: row ``r`` shifted by ``pixel_shift_by_row[r]`` columns), scored
against SemanticKITTI: why Ouster sweeps are destaggered by default.

KITTI 00 frames 0-2 (HDL-64, organised about their azimuths) are staggered with the first 64
shifts of each shared Ouster sensor's metadata, scaled to the image's columns; the sensor model
carries the shift, so every slot keeps its point; the labels are shifted back and scored per point.

Usage: ``python scripts/stagger_effect.py [KITTI_DIR] [OUSTER_PCAP_DIR]``
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from data_tools import open_dataset
from prc_slam import labels as L
from prc_slam.evaluation.metrics import ConfusionAccumulator
from prc_slam.evaluation.scoring import SOLID_CLASSES
from prc_slam.prc.algorithm import prc_block, warm_up
from prc_slam.prc.config import PRCConfig
from prc_slam.prc.ground import GroundState

ROOT = Path(__file__).resolve().parents[2] / "shared" / "data"


def pixel_shifts(meta: Path, rows: int, cols: int) -> np.ndarray:
    """The first ``rows`` of the metadata's ``pixel_shift_by_row``, scaled to ``cols`` columns."""

    def find(d: object) -> list | None:
        if isinstance(d, dict):
            for k, v in d.items():
                found = v if k == "pixel_shift_by_row" else find(v)
                if found is not None:
                    return found
        return None

    shift = np.asarray(find(json.loads(meta.read_text())), float)[:rows]
    return np.round(shift * cols / 1024).astype(int)


def main() -> None:
    kitti = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "kitti00"
    pcaps = Path(sys.argv[2]) if len(sys.argv) > 2 else ROOT / "ouster" / "pcaps"
    warm_up()
    cfg = PRCConfig.preset("multibeam")
    ds = open_dataset(kitti)
    scans = [ds[i] for i in range(3)]
    for meta in [None, *sorted(pcaps.glob("*.json"))]:
        conf, state = ConfusionAccumulator(), GroundState()
        for scan in scans:
            rows, cols = scan.shape
            if meta is None:
                labels = prc_block(scan.ranges, cfg, sensor=scan.sensor, wrap=True, ground_state=state).labels
            else:
                sh = pixel_shifts(meta, rows, cols)
                staggered = np.stack([np.roll(scan.ranges[r], -sh[r]) for r in range(rows)])
                sensor = dataclasses.replace(scan.sensor, column_shift=sh.astype(float))
                out = prc_block(staggered, cfg, sensor=sensor, wrap=True, ground_state=state).labels
                labels = np.stack([np.roll(out[r], sh[r]) for r in range(rows)])
            conf.add(scan.reference_labels(), scan.per_point(labels))
        f1 = {k: v["f1"] for k, v in conf.per_class().items()}
        name = "aligned" if meta is None else f"staggered as {meta.stem}"
        print(
            f"{name:40s} ground F1 {f1['ground']:.3f}  building {f1['building']:.3f}  vegetation "
            f"{f1['vegetation']:.3f}  solid -> noise {conf.fraction(SOLID_CLASSES, L.NOISE):.2%}"
        )


if __name__ == "__main__":
    main()
