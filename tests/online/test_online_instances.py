"""Per-instance vehicle scores by range band (``prc_slam.evaluation.scoring.InstanceBands``), hand-computed."""

from __future__ import annotations

import numpy as np
import pytest

from prc_slam import labels as L
from prc_slam.evaluation.scoring import InstanceBands, band_name, range_band_rows
from prc_slam.jobs.report import classification_section

V, VEG, B = L.VEHICLE, L.VEGETATION, L.BUILDING


def _car(n: int, x: float, y: float, n_vehicle: int, n_veg: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` returns around (x, y, 0.8); the first ``n_vehicle`` predicted vehicle, the next ``n_veg``
    vegetation, the rest building."""
    xyz = np.column_stack([np.full(n, x), np.full(n, y) + np.linspace(-0.5, 0.5, n), np.full(n, 0.8)])
    pred = np.full(n, B, np.uint8)
    pred[:n_vehicle] = V
    pred[n_vehicle : n_vehicle + n_veg] = VEG
    return xyz, pred


def _frame() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Four cars: 40 returns at 5 m (20 vehicle: found, exactly half), 30 at 15 m (14 vehicle: missed,
    12 vegetation), 25 at 25 m (25 vehicle), 10 at 35 m (too few to be present, all vehicle); and
    5 building returns at 6 m labelled vehicle (false positives) and 3 ground returns at 12 m."""
    parts = [_car(40, 5.0, 0.0, 20), _car(30, 0.0, -15.0, 14, 12), _car(25, 25.0, 0.0, 25), _car(10, 35.0, 0.0, 10)]
    ref = np.concatenate([np.full(len(p[0]), V, np.uint8) for p in parts])
    inst = np.concatenate([np.full(len(p[0]), k + 1, np.uint32) for k, p in enumerate(parts)])
    xyz = np.concatenate([p[0] for p in parts])
    pred = np.concatenate([p[1] for p in parts])
    fp_xyz = np.column_stack([np.full(5, 6.0), np.zeros(5), np.ones(5)])
    g_xyz = np.column_stack([np.full(3, 12.0), np.zeros(3), np.zeros(3)])
    ref = np.concatenate([ref, np.full(5, B, np.uint8), np.full(3, L.GROUND, np.uint8)])
    inst = np.concatenate([inst, np.full(5, 9, np.uint32), np.zeros(3, np.uint32)])
    pred = np.concatenate([pred, np.full(5, V, np.uint8), np.full(3, L.GROUND, np.uint8)])
    return ref, inst, pred, np.concatenate([xyz, fp_xyz, g_xyz])


def test_instances_and_points_by_range_band():
    acc = InstanceBands()
    acc.add(*_frame())
    out = acc.to_json()
    bands = {r["band"]: r for r in out["bands"]}
    assert list(bands) == ["0-10", "10-20", "20-30", "30-40", "40+"]
    assert (bands["0-10"]["present"], bands["0-10"]["found"]) == (1, 1)  # half labelled: found
    assert (bands["10-20"]["present"], bands["10-20"]["found"]) == (1, 0)  # 14 of 30: missed
    assert (bands["20-30"]["present"], bands["20-30"]["found"]) == (1, 1)
    assert (bands["30-40"]["present"], bands["30-40"]["found"]) == (0, 0)  # 10 returns: not present
    assert bands["30-40"]["found_share"] is None
    # points: 0-10 m holds the 40 car returns and the 5 false positives
    assert bands["0-10"]["points"] == 40
    assert bands["0-10"]["recall"] == pytest.approx(20 / 40)
    assert bands["0-10"]["precision"] == pytest.approx(20 / 25)
    assert bands["10-20"]["vegetation_share"] == pytest.approx(12 / 30)
    assert bands["10-20"]["recall"] == pytest.approx(14 / 30)
    assert bands["30-40"]["recall"] == pytest.approx(1.0)  # points count even when the instance does not
    assert bands["40+"]["points"] == 0 and bands["40+"]["recall"] is None and bands["40+"]["max_m"] is None
    near = out["within_20"]
    assert (near["present"], near["found"], near["points"]) == (2, 1, 70)
    assert near["found_share"] == pytest.approx(0.5)
    assert near["precision"] == pytest.approx(34 / 39)


def test_instance_range_is_that_of_its_mean_return():
    """A car from 9 to 12 m whose mean lies at 10.5 m belongs to 10-20, though some returns are in 0-10."""
    xyz = np.column_stack([np.linspace(9.0, 12.0, 30), np.zeros(30), np.full(30, 0.8)])
    acc = InstanceBands()
    acc.add(np.full(30, V, np.uint8), np.full(30, 3, np.uint32), np.full(30, V, np.uint8), xyz)
    present = {r["band"]: r["present"] for r in acc.to_json()["bands"]}
    assert present == {"0-10": 0, "10-20": 1, "20-30": 0, "30-40": 0, "40+": 0}


def test_frames_accumulate_and_merge():
    a, b = InstanceBands(), InstanceBands()
    a.add(*_frame())
    a.add(*_frame())
    b.add(*_frame())
    b.merge(b.__class__())
    c = InstanceBands()
    c.merge(b)
    c.merge(b)
    assert a.to_json() == c.to_json()
    assert a.to_json()["within_20"]["present"] == 4


def test_mismatched_lengths_are_named():
    ref, inst, pred, xyz = _frame()
    with pytest.raises(ValueError, match="instance scores"):
        InstanceBands().add(ref, inst, pred[:-1], xyz)


def test_table_rows_and_report_section():
    acc = InstanceBands()
    acc.add(*_frame())
    by_range = acc.to_json()
    header, rows = range_band_rows(by_range)
    assert header[0] == "range (m)" and rows[0][:3] == ["0-10", "1 of 1", "1.000"] and rows[-1][0] == "0-20"
    text = classification_section({"per_class": {}, "vehicle_by_range": by_range}, "t")
    assert "No reference labels" in text  # without per-class scores the section says so and stops
    per_class = {"vehicle": {"support": 100, "precision": 0.9, "recall": 0.8, "f1": 0.85}}
    text = classification_section({"per_class": per_class, "vehicle_by_range": by_range}, "t")
    assert "| 10-20 | 0 of 1 |" in text and "| 0-20 | 1 of 2 | 0.500 |" in text


def test_band_names():
    assert band_name(0.0, 10.0) == "0-10" and band_name(40.0, np.inf) == "40+"


def test_detect_reports_vehicles_by_range_on_the_street(tmp_path):
    """``detect`` on two simulated street sweeps: the metrics carry the bands, the instances present
    there are those of the frames (counted again by hand) and the report shows the table."""
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.jobs.classify import detect_job
    from prc_slam.jobs.common import open_input

    root = write_sequence(Simulator(SimConfig(scene="street", sensor="vlp16", frames=2, seed=3)), tmp_path / "s")
    metrics, _ = detect_job(root)
    by_range = metrics["vehicle_by_range"]
    present = sum(r["present"] for r in by_range["bands"])
    dataset, n = open_input(root)
    expected = 0
    for i in range(n):
        scan = dataset[i]
        veh = scan.gt_labels == L.VEHICLE
        _, counts = np.unique(scan.gt_instance[veh], return_counts=True)
        expected += int((counts >= 20).sum())
    assert present == expected > 0
    assert metrics["objects"]["vehicle"]["present"] == expected  # the existing count agrees
    assert "Vehicles by range" in classification_section(metrics, "t")
